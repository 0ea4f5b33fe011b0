"""``convodrive demo``, the main job: every body we ship, from a conversation (the bundled dialogue's first
seconds here), in real time."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.motion.npz import load_clip
from convodrive.pipeline.demo import SIDE_BY_SIDE_GENERATORS, side_by_side
from convodrive.samples import bundled_dialogue
from tests.conftest import run_cli

pytestmark = [pytest.mark.mujoco, pytest.mark.gl, pytest.mark.ffmpeg, pytest.mark.hardware]


def _ffprobe(path: Path) -> dict:
    out = subprocess.run(
        [
            "ffprobe",
            "-v",
            "error",
            "-show_entries",
            "stream=codec_type,codec_name,r_frame_rate,pix_fmt:format=duration",
            "-of",
            "json",
            str(path),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout)


SECONDS = 6
FRAMES = SECONDS * 30


@pytest.fixture
def short_dialogue(tmp_path: Path) -> Path:
    """The bundled dialogue's first six seconds (both voices speak in them): the demo's every step
    on a fifth of its real-time run."""
    voices, rate = sf.read(bundled_dialogue(), dtype="float32")
    path = tmp_path / "short.wav"
    sf.write(path, voices[: SECONDS * rate], rate, subtype="PCM_16")
    return path


@pytest.mark.slow
@pytest.mark.xdist_group("cpu_hogs")  # its servo head runs on the wall clock: not beside the DDP test
def test_demo_drives_every_body_and_reports(short_dialogue: Path, tmp_path: Path) -> None:
    out_dir = tmp_path / "demo"
    out = run_cli("demo", "--audio", str(short_dialogue), "--out", str(out_dir), timeout=600)
    assert out.returncode == 0, out.stderr
    for name in (
        "motion.npz",
        "motion.bvh",
        "motion_livelink.csv",
        "avatar.mp4",
        "avatar_contact.png",
        "mujoco.mp4",
        "run_report.json",
    ):
        assert (out_dir / name).is_file(), name
        assert str(out_dir / name) in out.stdout, f"the demo prints where {name} is"
    report = json.loads((out_dir / "run_report.json").read_text())
    assert report["mode"] == "realtime", "a servo head is driven at 30 fps on the wall clock"
    assert report["frames"] == report["expected_frames"] == FRAMES
    assert report["audio"]["path"] == str(short_dialogue)
    assert abs(report["drift_frames"]) < 1.0
    backends = report["backends"]
    for name in ("record", "render", "mujoco"):
        assert backends[name]["frames_sent"] == FRAMES, f"file outputs get every frame ({name})"
    for name in ("render", "mujoco", "dynamixel"):  # heavy and hardware backends: out of the clock's process
        process = backends[name]["report"]["process"]
        assert process["exit"] == "exit code 0" and process["pid"], name
    head = backends["dynamixel"]
    assert head["frames_sent"] >= 0.9 * FRAMES and head["errors"] == 0
    assert head["report"]["torque_off"] is True
    # On a loaded machine a status packet may come late and be retried; that is named, and nothing else may be.
    assert all(f.startswith(("lost_replies:", "bad_crc:")) for f in head["report"]["faults"]), head["report"]["faults"]
    assert load_clip(out_dir / "motion.npz").num_frames == FRAMES
    for video in ("avatar.mp4", "mujoco.mp4"):
        info = _ffprobe(out_dir / video)
        kinds = {s["codec_type"]: s for s in info["streams"]}
        assert kinds["video"]["r_frame_rate"] == "30/1" and kinds["video"]["pix_fmt"] == "yuv420p"
        assert "audio" in kinds
        assert abs(float(info["format"]["duration"]) - SECONDS) <= 1 / 30 + 1e-3
    # Then the three generators side by side, each either filmed or named with why it is not.
    films = json.loads((out_dir / "side_by_side_report.json").read_text())["backends"]["render"]["report"]
    shown = [name for name in SIDE_BY_SIDE_GENERATORS if f"side by side without {name}:" not in out.stdout]
    assert "procedural" in shown and films["takes"] == len(shown)
    assert f"wrote {out_dir / 'side_by_side.mp4'} ({', '.join(shown)} side by side)" in out.stdout
    info = _ffprobe(out_dir / "side_by_side.mp4")
    assert {s["codec_type"] for s in info["streams"]} == {"video", "audio"}
    assert abs(float(info["format"]["duration"]) - SECONDS) <= 1 / 30 + 1e-3


def test_demo_audio_that_is_not_there_is_one_line(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.wav"
    out = run_cli("demo", "--audio", str(missing), "--only", "record", "--out", str(tmp_path / "demo"))
    assert out.returncode == 2 and str(missing) in out.stderr and len(out.stderr.splitlines()) == 1, out.stderr
    assert not (tmp_path / "demo").exists()


def test_side_by_side_films_each_generator_that_runs_captioned_and_names_the_others(
    short_dialogue: Path, tmp_path: Path
) -> None:
    films = side_by_side(
        tmp_path, generators=("procedural", "no-such-model", "procedural"), resolution="160x160", audio=short_dialogue
    )
    assert films.generators == ["procedural", "procedural"]
    assert "unknown generator 'no-such-model'" in films.skipped["no-such-model"]
    info = _ffprobe(films.video)
    video = next(s for s in info["streams"] if s["codec_type"] == "video")
    assert "audio" in {s["codec_type"] for s in info["streams"]}
    frame = _frame_at(films.video, 3.0)
    assert frame.shape == (160, 320, 3), "two takes of 160x160 side by side"
    assert video["r_frame_rate"] == "30/1"
    # Each tile's caption: white text on a dark box in its top-left corner, background elsewhere.
    for left in (0, 160):
        corner = frame[6:20, left + 6 : left + 60].astype(int)
        background = frame[6:20, left + 130 : left + 156].astype(int)
        assert np.median(corner.sum(axis=2)) < 0.6 * np.median(background.sum(axis=2)), "the caption's dark box"
        assert (corner.min(axis=2) > 200).sum() > 20, "the caption's white letters"


def _frame_at(video: Path, seconds: float) -> np.ndarray:
    import imageio_ffmpeg

    out = subprocess.run(
        [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-v",
            "error",
            "-ss",
            str(seconds),
            "-i",
            str(video),
            "-frames:v",
            "1",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
            "-",
        ],
        capture_output=True,
        check=True,
    )
    width, height = (int(v) for v in _size(video))
    return np.frombuffer(out.stdout, np.uint8).reshape(height, width, 3)


def _size(video: Path) -> tuple[str, str]:
    out = subprocess.run(
        [
            "ffprobe",
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=width,height",
            "-of",
            "csv=p=0",
            str(video),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    width, height = out.stdout.strip().split(",")
    return width, height
