"""The replay generator: the audio sets length and clock, the motion file sets everything else."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from convodrive.audio.source import AudioChunk, DyadicAudio
from convodrive.generators.replay import ReplayGenerator
from convodrive.motion.bvh import write_bvh
from convodrive.motion.channels import ConversationState
from convodrive.motion.clip import MotionClip
from convodrive.motion.livelink import write_livelink_csv
from convodrive.motion.npz import save_clip
from convodrive.plugins import GENERATOR_GROUP, load_plugin
from convodrive.plumbing.errors import InputFileError, UserError


def ramp_clip(num_frames: int, fps: float) -> MotionClip:
    """Frame i: head yaw 0.01 i rad, translation x i mm, jawOpen i / num_frames, states cycling."""
    clip = MotionClip.neutral(num_frames, fps=fps)
    clip.pose[:, 15, 1] = 0.01 * np.arange(num_frames)
    clip.translation[:, 0] = np.arange(num_frames) / 1000
    clip.face[:, 17] = np.arange(num_frames) / num_frames
    clip.vad[:, 0] = np.arange(num_frames) % 2
    clip.state[:] = np.arange(num_frames) % 4
    return clip


def audio(seconds: float) -> DyadicAudio:
    n = int(seconds * 16000)
    return DyadicAudio(np.zeros(n, np.float32), np.zeros(n, np.float32))


def saved(tmp_path: Path, clip: MotionClip) -> str:
    return str(save_clip(clip, tmp_path / "m.npz"))


def test_plays_the_clip_then_holds_the_last_frame(tmp_path: Path) -> None:
    clip = ramp_clip(45, 30)
    gen = ReplayGenerator({"motion": saved(tmp_path, clip)})
    frames = list(gen.stream(audio(2.0).chunks()))
    assert len(frames) == 60
    assert [f.time for f in frames] == pytest.approx([k / 30 for k in range(60)])
    yaw = np.array([f.pose[15, 1] for f in frames])
    np.testing.assert_allclose(yaw[:45], clip.pose[:, 15, 1], atol=1e-6)
    np.testing.assert_allclose(yaw[45:], clip.pose[44, 15, 1], atol=1e-6)
    assert [int(f.state) for f in frames[:45]] == list(clip.state)
    assert frames[-1].state == ConversationState(int(clip.state[44]))
    np.testing.assert_allclose([f.vad[0] for f in frames[:45]], clip.vad[:, 0])


def test_streams_as_the_audio_arrives(tmp_path: Path) -> None:
    gen = ReplayGenerator({"motion": saved(tmp_path, ramp_clip(30, 30))})
    consumed = []

    def chunks() -> Iterator[AudioChunk]:
        for c in audio(1.0).chunks():
            consumed.append(c.start)
            yield c

    out = []
    for f in gen.stream(chunks()):
        out.append((round(f.time * 30), len(consumed)))
    # 1600 samples = 100 ms = 3 frames per chunk, released as soon as their chunk arrives.
    assert out == [(k, k // 3 + 1) for k in range(30)]


@pytest.mark.parametrize("fps", [60, 20])
def test_resamples_other_rates(tmp_path: Path, fps: int) -> None:
    clip = ramp_clip(fps, fps)  # one second
    gen = ReplayGenerator({"motion": saved(tmp_path, clip)})
    frames = list(gen.stream(audio(1.0).chunks()))
    assert len(frames) == 30
    t = np.arange(30) / 30
    source = np.minimum(t * fps, fps - 1)  # fractional source frame, held at the end
    np.testing.assert_allclose([f.translation[0] for f in frames], source / 1000, atol=1e-6)
    yaw = [Rotation.from_rotvec(f.pose[15]).as_euler("YXZ")[0] for f in frames]
    np.testing.assert_allclose(yaw, 0.01 * source, atol=1e-5)


def test_reads_bvh(tmp_path: Path) -> None:
    clip = ramp_clip(30, 30)
    path = write_bvh(clip, tmp_path / "m.bvh")
    frames = list(ReplayGenerator({"motion": str(path)}).stream(audio(1.0).chunks()))
    np.testing.assert_allclose([f.pose[15, 1] for f in frames], clip.pose[:, 15, 1], atol=1e-5)


def test_generate_offline_takes(tmp_path: Path) -> None:
    gen = load_plugin(GENERATOR_GROUP, "replay")({"motion": saved(tmp_path, ramp_clip(10, 30))})
    clips = gen.generate(audio(0.5), seed=1, num_samples=2)
    assert [c.num_frames for c in clips] == [15, 15]


def test_missing_option_and_bad_files(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="^generator 'replay' needs a motion file: ") as err:
        ReplayGenerator({})
    assert "\n" not in str(err.value)
    with pytest.raises(InputFileError, match="no such file"):
        ReplayGenerator({"motion": str(tmp_path / "absent.npz")})
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputFileError, match="unsupported motion format ..txt."):
        ReplayGenerator({"motion": str(tmp_path / "notes.txt")})
    empty = save_clip(MotionClip.neutral(0), tmp_path / "empty.npz")
    with pytest.raises(InputFileError, match="no frames"):
        ReplayGenerator({"motion": str(empty)})


def test_a_clip_longer_than_the_audio_is_cut_with_a_warning(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = write_bvh(ramp_clip(90, 30), tmp_path / "long.bvh")  # 3 s of motion, no face
    gen = ReplayGenerator({"motion": str(path)})
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert warnings == [f"replay: {path}: plays no face (every blendshape channel is 0)"]
    frames = list(gen.stream(audio(1.0).chunks()))
    assert len(frames) == 30
    cut = f"{path}: the clip lasts 3.00 s but the audio 1.00 s: its last 2.00 s are not played"
    assert [r.getMessage() for r in caplog.records][-1] == f"replay: {cut}"
    assert gen.report()["warnings"] == [f"{path}: plays no face (every blendshape channel is 0)", cut]


def test_a_clip_shorter_than_the_audio_holds_with_a_warning(tmp_path: Path) -> None:
    gen = ReplayGenerator({"motion": saved(tmp_path, ramp_clip(15, 30))})
    list(gen.stream(audio(1.0).chunks()))
    assert gen.report()["warnings"] == [
        f"{tmp_path / 'm.npz'}: the clip lasts 0.50 s but the audio 1.00 s: its last frame is held for 0.50 s"
    ]
    exact = ReplayGenerator({"motion": saved(tmp_path, ramp_clip(30, 30))})
    list(exact.stream(audio(1.0).chunks()))
    assert exact.report()["warnings"] == []


def test_take_k_plays_file_k(tmp_path: Path) -> None:
    slow, fast = ramp_clip(30, 30), ramp_clip(30, 30)
    fast.pose[:, 15, 1] *= 2
    a, b = save_clip(slow, tmp_path / "a.npz"), write_bvh(fast, tmp_path / "b.bvh")
    gen = ReplayGenerator({"motion": [str(a), str(b)]})
    takes = list(gen.stream_takes(audio(1.0).chunks(), seeds=[0, 1, 2]))
    assert len(takes) == 30 and all(len(t) == 3 for t in takes)
    np.testing.assert_allclose([t[0].pose[15, 1] for t in takes], slow.pose[:, 15, 1], atol=1e-5)
    np.testing.assert_allclose([t[1].pose[15, 1] for t in takes], fast.pose[:, 15, 1], atol=1e-5)
    np.testing.assert_allclose([t[2].pose[15, 1] for t in takes], slow.pose[:, 15, 1], atol=1e-5)


def test_reads_live_link_csv(tmp_path: Path) -> None:
    clip = ramp_clip(30, 30)
    path = write_livelink_csv(clip, tmp_path / "take.csv")
    frames = list(ReplayGenerator({"motion": str(path)}).stream(audio(1.0).chunks()))
    np.testing.assert_allclose([f.face[17] for f in frames], clip.face[:, 17], atol=1e-6)


def test_bad_motion_option_is_one_line() -> None:
    with pytest.raises(UserError, match="generator replay: option 'motion' must be"):
        ReplayGenerator({"motion": 5})
    with pytest.raises(UserError, match="unknown option 'moton' \\(did you mean 'motion'\\?\\)"):
        ReplayGenerator({"moton": "a.npz"})
