"""The render backend and ``convodrive render`` end to end: real GL, real H.264, real ffprobe."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from convodrive.backends.base import Session
from convodrive.cli.main import main
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.clip import MotionClip
from convodrive.motion.npz import save_clip
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.motion.targets import TargetFrame, TargetSpec

RES = 96


@pytest.fixture(scope="module")
def speech(tmp_path_factory) -> Path:
    """About a second of espeak-ng speech, resampled to 44.1 kHz stereo as a user's file might be."""
    import soundfile as sf

    from convodrive.audio.synth import speak

    folder = tmp_path_factory.mktemp("speech")
    data = speak("Hello, nice to see you.", sample_rate=44100)
    path = folder / "speech.wav"
    sf.write(path, np.stack([data, 0.3 * data], 1), 44100)
    return path


def _clip(frames: int, phase: float = 0.0) -> MotionClip:
    clip = MotionClip.neutral(frames)
    t = np.arange(frames) / 30.0
    clip.pose[:, JOINT_INDEX["left_shoulder"], 2] = -1.2 + 0.3 * np.sin(3 * t + phase)
    clip.pose[:, JOINT_INDEX["right_shoulder"], 2] = 1.2
    clip.pose[:, JOINT_INDEX["head"], 1] = 0.2 * np.sin(2 * t + phase)
    clip.face[:, BLENDSHAPE_INDEX["jawOpen"]] = 0.5 + 0.5 * np.sin(9 * t)
    return clip


def _probe(path: Path) -> dict:
    out = subprocess.run(
        ["ffprobe", "-v", "error", "-show_streams", "-show_format", "-of", "json", str(path)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout)


def _audio_seconds(path: Path) -> float:
    import soundfile as sf

    return sf.info(str(path)).duration


@pytest.mark.gl
@pytest.mark.ffmpeg
@pytest.mark.espeak
def test_backend_films_takes_with_audio(tmp_path, speech):
    from convodrive.audio.source import motion_frames_for
    from convodrive.backends.render import RenderBackend

    duration = _audio_seconds(speech)
    n = motion_frames_for(duration)
    clip = _clip(n)
    backend = RenderBackend({"camera": "face", "resolution": f"{RES}x{RES}"})
    session = Session(out_dir=tmp_path, audio_path=speech, duration=duration, num_frames=n, num_samples=1)
    backend.open(TargetSpec.empty(), session)
    for i in range(n):
        backend.send(TargetFrame(index=i, time=i / 30, values=np.zeros(0), takes=(clip.frame(i),)))
    backend.close()
    report = backend.report()
    video, sheet = tmp_path / "avatar.mp4", tmp_path / "avatar_contact.png"
    assert backend.outputs() == [video, sheet]
    assert report["frames"] == n and report["resolution"] == [RES, RES] and report["gl_platform"] in ("egl", "osmesa")
    info = _probe(video)
    v = next(s for s in info["streams"] if s["codec_type"] == "video")
    assert v["codec_name"] == "h264" and v["pix_fmt"] == "yuv420p" and v["r_frame_rate"] == "30/1"
    assert (v["width"], v["height"]) == (RES, RES) and int(v["nb_frames"]) == n
    assert any(s["codec_type"] == "audio" for s in info["streams"])
    assert abs(float(v["duration"]) - duration) <= 1 / 30 + 1e-3
    import imageio.v3 as iio

    contact = iio.imread(sheet)
    assert contact.ndim == 3 and contact.shape[1] > 2 * 320  # several thumbnails per row
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind


@pytest.mark.gl
@pytest.mark.ffmpeg
@pytest.mark.espeak
def test_cli_renders_npz_and_bvh_side_by_side(tmp_path, speech):
    from convodrive.motion.bvh import write_bvh

    a, b = tmp_path / "a.npz", tmp_path / "b.bvh"
    save_clip(_clip(40), a)
    write_bvh(_clip(25, phase=1.0), b)
    out = tmp_path / "out" / "grid.mp4"
    rc = main(
        [
            "render",
            str(a),
            str(b),
            "--audio",
            str(speech),
            "--camera",
            "upper",
            "--resolution",
            f"{RES}x{RES + 32}",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    info = _probe(out)
    v = next(s for s in info["streams"] if s["codec_type"] == "video")
    assert (v["width"], v["height"]) == (2 * RES, RES + 32)  # two takes, side by side
    assert v["r_frame_rate"] == "30/1"
    assert any(s["codec_type"] == "audio" for s in info["streams"])
    assert abs(float(v["duration"]) - _audio_seconds(speech)) <= 1 / 30 + 1e-3
    assert (tmp_path / "out" / "grid_contact.png").is_file()
    import imageio.v3 as iio

    frames = iio.imread(out, index=None)
    left, right = frames[10][:, :RES].astype(int), frames[10][:, RES:].astype(int)
    assert np.abs(left - right).mean() > 1.0  # the two takes differ: both were drawn


@pytest.mark.parametrize(
    "args, needle",
    [
        (["missing.npz"], "missing.npz: no such file"),
        (["clip.txt"], "unsupported motion format '.txt'"),
        # The resolution is the render backend's option: checked once the backend loads.
        pytest.param(["{clip}", "--resolution", "512by512"], "expected WIDTHxHEIGHT", marks=pytest.mark.gl),
        pytest.param(["{clip}", "--resolution", "511x512"], "must be even", marks=pytest.mark.gl),
        (["{clip}", "--audio", "nope.wav"], "nope.wav: no such file"),
        (["{clip}", "--out", "video.avi"], "must be an .mp4"),
    ],
)
def test_user_errors_are_one_line(tmp_path, capsys, monkeypatch, args, needle):
    monkeypatch.chdir(tmp_path)
    save_clip(_clip(3), tmp_path / "clip.npz")
    (tmp_path / "clip.txt").write_text("not motion")
    rc = main(["render", *[a.format(clip="clip.npz") for a in args]])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


@pytest.mark.parametrize(
    "flags, needle",
    [
        (["--camera", "side"], "option 'camera' must be one of full, upper, face, got 'side'"),
        (["--camera", "fce"], "(did you mean 'face'?)"),
        (["--resolution", "511x512"], "must be even"),
        (["--labels", "x" * 5000], "option 'labels' must be at most 4096 characters"),
    ],
)
def test_bad_flag_values_are_one_line_naming_the_option(tmp_path, capsys, flags, needle):
    """The render flags are the render backend's options: checked before any work (the clip
    need not even exist), one line naming the backend and the option."""
    rc = main(["render", str(tmp_path / "x.npz"), *flags])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("convodrive: error: backend render: ") and needle in err
    assert not list(tmp_path.iterdir())


def test_backend_options_are_checked():
    from convodrive.backends.render import RenderBackend
    from convodrive.plumbing.errors import UserError

    for options in ({"camera": "top"}, {"resolution": "100"}, {"filename": "a.gif"}, {"zoom": 2}):
        with pytest.raises(UserError):
            RenderBackend(options)
    assert RenderBackend({}).default_profile is None and RenderBackend.realtime is False


@pytest.mark.gl
def test_no_headless_gl_is_one_line(tmp_path):
    """A platform that cannot work (here a bogus one) ends in one line, not a traceback."""
    from tests.conftest import run_cli

    save_clip(_clip(3), tmp_path / "c.npz")
    proc = run_cli("render", str(tmp_path / "c.npz"), env={"PYOPENGL_PLATFORM": "nonesuch"})
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "no headless OpenGL works" in lines[0]


@pytest.mark.gl
def test_contact_sheet_keeps_frames_evenly_spread():
    from convodrive.backends.render import ContactSheet

    sheet = ContactSheet(cells=4)
    for i in range(100):
        sheet.offer(i, np.full((8, 8, 3), i, np.uint8))
    kept = [i for i, _, _ in sheet.kept]
    assert len(kept) <= 8 and kept[0] == 0
    assert len(set(np.diff(kept))) == 1  # one stride


@pytest.mark.gl
@pytest.mark.ffmpeg
def test_window_without_display_degrades_to_file_only(tmp_path, monkeypatch):
    from convodrive.backends.render import RenderBackend

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    backend = RenderBackend({"window": True, "resolution": "32x32"})
    assert backend.realtime is False  # no window: stays an offline file backend
    backend.open(TargetSpec.empty(), Session(out_dir=tmp_path))
    backend.send(TargetFrame(index=0, time=0.0, values=np.zeros(0), takes=(MotionClip.neutral(1).frame(0),)))
    backend.close()
    health = backend.health()
    assert health["status"] == "degraded" and "no display" in health["note"]
    assert (tmp_path / "avatar.mp4").is_file()


@pytest.fixture
def x_display():
    """A virtual X display (Xvfb) for the live window, as a desktop would provide."""
    if not shutil.which("Xvfb"):
        pytest.skip("Xvfb is not installed (scripts/setup.sh --dev installs it)")
    import os
    import time

    number = next(
        n
        for n in range(91, 200)
        if not os.path.exists(f"/tmp/.X11-unix/X{n}") and not os.path.exists(f"/tmp/.X{n}-lock")
    )
    proc = subprocess.Popen(
        ["Xvfb", f":{number}", "-screen", "0", "320x240x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 10
    while not os.path.exists(f"/tmp/.X11-unix/X{number}") and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    try:
        yield f":{number}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.gl
@pytest.mark.ffmpeg
@pytest.mark.xvfb
def test_live_window_shows_the_frames_on_a_display(tmp_path, monkeypatch, x_display):
    from convodrive.backends.render import RenderBackend

    monkeypatch.setenv("DISPLAY", x_display)
    backend = RenderBackend({"window": True, "camera": "face", "resolution": "64x64"})
    assert backend.realtime is True, "a live window is paced by the wall clock"
    backend.open(TargetSpec.empty(), Session(out_dir=tmp_path))
    clip = _clip(3)
    for i in range(3):
        backend.send(TargetFrame(index=i, time=i / 30, values=np.zeros(0), takes=(clip.frame(i),)))
    photo = backend._window._photo
    shown = {photo.get(x, y) for x in range(0, 64, 8) for y in range(0, 64, 8)}
    size = (photo.width(), photo.height())
    backend.close()
    assert size == (64, 64)
    assert len(shown) > 4, "the window shows the rendered avatar, not a blank image"
    assert backend.health()["status"] == "ok" and "note" not in backend.health()
    assert (tmp_path / "avatar.mp4").is_file(), "the video is still written beside the window"


@pytest.mark.gl
@pytest.mark.ffmpeg
@pytest.mark.xvfb
def test_a_live_window_run_keeps_every_frame_of_the_video_or_says_it_did_not(tmp_path, monkeypatch, x_display, speech):
    """With a window the renderer is real time and skips what it cannot render in time; the mp4
    still has one frame per frame of the run (the last image repeated) and the report says how
    many repeat and that render is degraded. A heavy setting makes the skips certain."""
    from convodrive.pipeline import DriveRequest, drive

    monkeypatch.setenv("DISPLAY", x_display)
    options = {"window": True, "resolution": "768x768", "antialias": True, "camera": "face"}
    result = drive(
        DriveRequest(audio=speech, backends=("render",), out_dir=tmp_path, backend_options={"render": options})
    )
    report = result.report
    assert report["mode"] == "realtime"
    render = report["backends"]["render"]
    frames = report["frames"]
    assert render["frames_dropped"] > 0, "768x768 with 4x MSAA cannot render at 30 fps on a CPU"
    info = _probe(tmp_path / "avatar.mp4")
    video = next(s for s in info["streams"] if s["codec_type"] == "video")
    assert int(video["nb_frames"]) == frames, "one video frame per frame of the run"
    assert render["report"]["frames_repeated"] == render["frames_dropped"]
    assert render["report"]["frames"] + render["report"]["frames_repeated"] == frames
    assert render["health"]["status"] == "degraded"
    assert f"repeats the previous image for {render['frames_dropped']} of {frames} frames" in render["health"]["reason"]
    assert "render     degraded" in result.summary_path.read_text()
