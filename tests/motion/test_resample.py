"""The one resampler: clips at any rate read as the 30 fps stream, the same frame by frame or whole."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from convodrive.motion.clip import MotionClip
from convodrive.motion.resample import ClipSampler, frames_covering, resample
from convodrive.motion.skeleton import JOINT_INDEX

HEAD = JOINT_INDEX["head"]


def turning_clip(num_frames: int, fps: float) -> MotionClip:
    """The head turns about a tilted axis by 0.05 rad a frame; jawOpen and x ramp; states cycle."""
    clip = MotionClip.neutral(num_frames, fps=fps)
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    clip.pose[:, HEAD] = 0.05 * np.arange(num_frames)[:, None] * axis
    clip.translation[:, 0] = np.arange(num_frames) / 100
    clip.face[:, 17] = np.arange(num_frames) / num_frames
    clip.vad[:, 1] = np.arange(num_frames) % 2
    clip.state[:] = np.arange(num_frames) % 4
    return clip


def test_a_clip_at_30_fps_comes_back_frame_for_frame() -> None:
    clip = turning_clip(20, 30)
    assert resample(clip) is clip
    out = ClipSampler(clip).resample()
    for key in ("pose", "translation", "face", "vad", "state"):
        np.testing.assert_allclose(getattr(out, key), getattr(clip, key), atol=1e-6)


def test_60_fps_takes_every_other_frame() -> None:
    clip = turning_clip(60, 60)
    out = resample(clip)
    assert out.fps == 30 and out.num_frames == 30
    np.testing.assert_allclose(out.pose, clip.pose[::2], atol=1e-6)
    np.testing.assert_array_equal(out.state, clip.state[::2])


def test_24_fps_slerps_rotations_and_lerps_the_rest() -> None:
    clip = turning_clip(24, 24)
    out = resample(clip)
    assert out.num_frames == frames_covering(clip) == 30
    t = np.arange(30) / 30
    source = np.minimum(t * 24, 23)  # fractional source frame, held at the end
    expected = Slerp(np.arange(24), Rotation.from_rotvec(clip.pose[:, HEAD]))(source).as_rotvec()
    np.testing.assert_allclose(out.pose[:, HEAD], expected, atol=1e-5)
    np.testing.assert_allclose(out.translation[:, 0], source / 100, atol=1e-6)
    np.testing.assert_allclose(out.face[:, 17], source / 24, atol=1e-6)
    nearest = np.minimum(np.floor(source + 0.5), 23).astype(int)
    np.testing.assert_array_equal(out.state, clip.state[nearest])


def test_past_the_end_the_last_frame_is_held() -> None:
    clip = turning_clip(10, 25)
    out = ClipSampler(clip).resample(40)
    held = np.arange(40) / 30 * 25 >= 9
    assert held.sum() > 20
    np.testing.assert_allclose(out.pose[held], np.broadcast_to(clip.pose[-1], out.pose[held].shape), atol=1e-6)


@pytest.mark.parametrize("fps", [24, 25, 48, 60, 29.97])
def test_streaming_frames_equal_the_whole_clip(fps: float) -> None:
    clip = turning_clip(37, fps)
    sampler = ClipSampler(clip)
    whole = sampler.resample(sampler.num_frames + 3)
    for k in range(whole.num_frames):
        frame = sampler.frame(k)
        assert frame.time == pytest.approx(k / 30)
        np.testing.assert_array_equal(frame.pose, whole.pose[k])
        np.testing.assert_array_equal(frame.face, whole.face[k])
        assert int(frame.state) == whole.state[k]


def test_an_empty_clip_cannot_be_sampled() -> None:
    with pytest.raises(ValueError):
        ClipSampler(MotionClip.neutral(0))
