"""``convodrive render`` is a pipeline run (replay into the render backend): a clip at another rate
animates exactly as ``drive --generator replay`` plays it, and the clip/audio mismatches are said."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.cli.main import main
from convodrive.motion.bvh import write_bvh
from convodrive.motion.bvh_read import read_bvh
from convodrive.motion.clip import MotionClip
from convodrive.motion.npz import load_clip
from convodrive.motion.resample import resample
from convodrive.motion.skeleton import JOINT_INDEX

pytestmark = [pytest.mark.gl, pytest.mark.ffmpeg]

RES = "64x64"


def waving_clip(num_frames: int, fps: float) -> MotionClip:
    """Big, fast arm and head motion, so that a frame sampled a little off shows in the pixels."""
    clip = MotionClip.neutral(num_frames, fps=fps)
    t = np.arange(num_frames) / fps
    clip.pose[:, JOINT_INDEX["left_shoulder"], 2] = -1.0 + 0.9 * np.sin(9 * t)
    clip.pose[:, JOINT_INDEX["left_elbow"], 1] = 1.2 * np.sin(7 * t)
    clip.pose[:, JOINT_INDEX["head"], 1] = 0.5 * np.sin(6 * t)
    return clip


def tone(path: Path, seconds: float) -> Path:
    t = np.arange(int(seconds * 16000)) / 16000
    sf.write(path, (0.2 * np.sin(2 * np.pi * 200 * t)).astype(np.float32), 16000)
    return path


def frames_of(video: Path) -> np.ndarray:
    import imageio.v3 as iio

    return np.asarray(iio.imread(video, index=None))


def test_render_and_drive_replay_animate_a_24_fps_bvh_alike(tmp_path: Path) -> None:
    bvh = write_bvh(waving_clip(24, 24), tmp_path / "wave.bvh")  # one second at 24 fps
    audio = tone(tmp_path / "tone.wav", 1.0)
    rendered = tmp_path / "render" / "wave.mp4"
    assert main(["render", str(bvh), "--audio", str(audio), "--resolution", RES, "--out", str(rendered)]) == 0
    driven = tmp_path / "drive"
    rc = main(
        ["drive", str(audio), "--generator", "replay", "--motion", str(bvh), "--backend", "render,record"]
        + ["-B", f"render.resolution={RES}", "--out", str(driven)]
    )
    assert rc == 0
    a, b = frames_of(rendered), frames_of(driven / "avatar.mp4")
    assert a.shape == b.shape and len(a) == 30
    assert np.abs(a.astype(int) - b.astype(int)).max() == 0, "the same clip must animate the same"
    # And both play the one resampler's frames: the recorder holds what the renderer was sent.
    expected = resample(read_bvh(bvh))
    np.testing.assert_allclose(load_clip(driven / "motion.npz").pose, expected.pose, atol=1e-5)
    # Consecutive frames differ: the arm moves, so a frame sampled at another time would show.
    assert np.abs(np.diff(a.astype(int), axis=0)).mean(axis=(1, 2, 3)).min() > 0.1


def test_without_audio_the_video_lasts_as_long_as_the_longest_clip(tmp_path: Path) -> None:
    from convodrive.motion.npz import save_clip

    a = save_clip(waving_clip(40, 30), tmp_path / "a.npz")
    b = write_bvh(waving_clip(50, 60), tmp_path / "b.bvh")  # 25 frames at 30 fps
    assert main(["render", str(a), str(b), "--resolution", RES]) == 0
    video = tmp_path / "a.mp4"
    frames = frames_of(video)
    assert frames.shape[:3] == (40, 64, 128)  # two takes side by side, the longer clip's length
    report = json.loads((tmp_path / "a_report.json").read_text())
    assert report["audio"] == {"path": None, "silence": True, "duration_s": 1.333}
    assert any("held for 0.50 s" in w for w in report["warnings"])
    assert (tmp_path / "a_contact.png").is_file()
    assert not (tmp_path / "run_report.json").exists(), "render keeps its report beside its video"


def test_a_clip_cut_by_shorter_audio_is_warned_about(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    bvh = write_bvh(waving_clip(60, 30), tmp_path / "long.bvh")
    audio = tone(tmp_path / "short.wav", 0.5)
    assert main(["render", str(bvh), "--audio", str(audio), "--resolution", RES]) == 0
    out = capsys.readouterr().out
    assert "warning: " + f"{bvh}: the clip lasts 2.00 s but the audio 0.50 s: its last 1.50 s are not played" in out
    assert f"warning: {bvh}: plays no face (every blendshape channel is 0)" in out
    assert len(frames_of(tmp_path / "long.mp4")) == 15


def test_every_render_option_but_the_file_names_is_a_flag(tmp_path: Path) -> None:
    """The flags are made from ``RenderOptions``: each option is one (``--out`` names the files),
    and a value reaches the backend as given: ``--labels no`` draws the caption "no"."""
    import dataclasses

    from convodrive.backends.render import RenderOptions
    from convodrive.cli.main import build_parser

    render = build_parser()._subparsers._group_actions[0].choices["render"]  # type: ignore[union-attr]
    flags = {s for a in render._actions for s in a.option_strings}
    for field in dataclasses.fields(RenderOptions):
        flag = "--" + field.name.replace("_", "-")
        assert (flag in flags) == (field.name not in ("filename", "contact_sheet")), flag
    clip = write_bvh(waving_clip(3, 30), tmp_path / "c.bvh")
    plain, captioned = tmp_path / "plain.mp4", tmp_path / "captioned.mp4"
    assert main(["render", str(clip), "--resolution", "96x96", "--out", str(plain)]) == 0
    assert main(["render", str(clip), "--resolution", "96x96", "--labels", "no", "--out", str(captioned)]) == 0
    a, b = frames_of(plain)[0].astype(int), frames_of(captioned)[0].astype(int)
    corner = np.abs(a[:24, :48] - b[:24, :48]).mean()
    rest = np.abs(a[48:] - b[48:]).mean()
    assert corner > 5 * max(rest, 0.1), (corner, rest)  # a caption in the top-left corner, nothing else
