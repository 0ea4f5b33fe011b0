"""The one resampler: a clip at any rate read as the canonical 30 fps stream.

Output frame k shows the clip at ``k / fps`` seconds. Between two clip frames, rotations are
slerped joint by joint, translation, face and voice activity are interpolated linearly, and the
conversation state is taken from the nearer frame. Past its end a clip holds its last frame.
Everything that plays a saved clip (the ``replay`` generator, and through it ``convodrive render``)
reads it through ``ClipSampler``, so one file animates the same everywhere.
"""

from __future__ import annotations

import math

import numpy as np

from convodrive import FPS
from convodrive.motion import rotations
from convodrive.motion.channels import ConversationState
from convodrive.motion.clip import MotionClip, MotionFrame

_EXACT = 1e-6
"""A position this close to a clip frame shows that frame itself (no interpolation round-off)."""


def frames_covering(clip: MotionClip, fps: float = FPS) -> int:
    """How many frames at ``fps`` cover the clip's duration (at least one)."""
    return max(1, math.ceil(clip.duration * fps - _EXACT))


class ClipSampler:
    """Reads ``clip`` at ``fps``: ``frame(k)`` for streaming, ``resample(n)`` for a whole clip."""

    def __init__(self, clip: MotionClip, fps: float = FPS) -> None:
        if clip.num_frames == 0:
            raise ValueError("cannot sample a clip with no frames")
        self.clip = clip
        self.fps = float(fps)
        self._quats = rotations.axis_angle_to_quat(clip.pose)

    @property
    def num_frames(self) -> int:
        """Frames at ``fps`` that cover the clip; later indices hold its last frame."""
        return frames_covering(self.clip, self.fps)

    def frame(self, index: int) -> MotionFrame:
        """Output frame ``index``, with ``time == index / fps``."""
        arrays = self._sample(np.array([index]))
        return MotionFrame(
            time=index / self.fps,
            pose=arrays["pose"][0],
            translation=arrays["translation"][0],
            face=arrays["face"][0],
            vad=arrays["vad"][0],
            state=ConversationState(int(arrays["state"][0])),
        )

    def resample(self, num_frames: int | None = None) -> MotionClip:
        """The first ``num_frames`` output frames (default: those covering the clip) as a clip at ``fps``."""
        count = self.num_frames if num_frames is None else int(num_frames)
        arrays = self._sample(np.arange(count))
        return MotionClip(**arrays, fps=self.fps, metadata=dict(self.clip.metadata))

    def _sample(self, indices: np.ndarray) -> dict[str, np.ndarray]:
        clip = self.clip
        last = clip.num_frames - 1
        position = np.minimum(indices / self.fps * clip.fps, last)
        i0 = np.floor(position + _EXACT).astype(np.int64)
        frac = np.clip(position - i0, 0.0, 1.0)
        frac[frac < _EXACT] = 0.0
        i1 = np.minimum(i0 + 1, last)
        weight = frac[:, None]

        def lerp(a: np.ndarray) -> np.ndarray:
            return ((1.0 - weight) * a[i0] + weight * a[i1]).astype(np.float32)

        moving = frac > 0.0
        pose = clip.pose[i0].astype(np.float32)
        if moving.any():
            t = np.broadcast_to(frac[moving, None], (int(moving.sum()), clip.pose.shape[1]))
            q = rotations.quat_slerp(self._quats[i0[moving]], self._quats[i1[moving]], t)
            pose[moving] = rotations.quat_to_axis_angle(q)
        return {
            "pose": pose,
            "translation": lerp(clip.translation),
            "face": lerp(clip.face),
            "vad": lerp(clip.vad),
            "state": np.where(frac < 0.5, clip.state[i0], clip.state[i1]).astype(np.int8),
        }


def resample(clip: MotionClip, fps: float = FPS, num_frames: int | None = None) -> MotionClip:
    """``clip`` at ``fps``; a clip already at that rate and length comes back unchanged."""
    if clip.num_frames and abs(clip.fps - fps) < 1e-9 and num_frames in (None, clip.num_frames):
        return clip
    return ClipSampler(clip, fps).resample(num_frames)
