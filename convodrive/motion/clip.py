"""Motion frames and clips: the canonical motion every part speaks (DESIGN, "The canonical motion").

A frame is one 30 fps instant: local joint rotations (axis-angle) on the canonical skeleton, root
translation, the 52 ARKit face channels, and who is talking. A clip is a run of frames in arrays,
which is how generators produce motion offline and how it is stored.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.motion.channels import NUM_BLENDSHAPES, ConversationState
from convodrive.motion.skeleton import NUM_JOINTS


@dataclasses.dataclass
class MotionFrame:
    """One instant of canonical motion. Arrays are float32 and owned by the frame."""

    time: float
    """Seconds on the run's clock: frame index / FPS."""
    pose: np.ndarray
    """(55, 3) local joint rotations, axis-angle, radians."""
    translation: np.ndarray
    """(3,) root displacement from its rest position, metres."""
    face: np.ndarray
    """(52,) ARKit blendshape weights in [0, 1], in ``ARKIT_NAMES`` order."""
    vad: np.ndarray
    """(2,) voice activity of self and of the partner, in [0, 1]."""
    state: ConversationState = ConversationState.SILENCE

    @classmethod
    def neutral(cls, time: float = 0.0) -> MotionFrame:
        return cls(
            time=time,
            pose=np.zeros((NUM_JOINTS, 3), np.float32),
            translation=np.zeros(3, np.float32),
            face=np.zeros(NUM_BLENDSHAPES, np.float32),
            vad=np.zeros(2, np.float32),
        )


@dataclasses.dataclass
class MotionClip:
    """A run of frames at ``fps``, stored as arrays with time on the first axis."""

    pose: np.ndarray  # (T, 55, 3) float32 axis-angle
    translation: np.ndarray  # (T, 3) float32
    face: np.ndarray  # (T, 52) float32 in [0, 1]
    vad: np.ndarray  # (T, 2) float32
    state: np.ndarray  # (T,) int8, ConversationState values
    fps: float = FPS
    metadata: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.pose)
        expected = {
            "pose": (n, NUM_JOINTS, 3),
            "translation": (n, 3),
            "face": (n, NUM_BLENDSHAPES),
            "vad": (n, 2),
            "state": (n,),
        }
        for name, shape in expected.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"MotionClip.{name} has shape {getattr(self, name).shape}, expected {shape}")

    @property
    def num_frames(self) -> int:
        return len(self.pose)

    @property
    def duration(self) -> float:
        return self.num_frames / self.fps

    def frame(self, index: int) -> MotionFrame:
        return MotionFrame(
            time=index / self.fps,
            pose=self.pose[index].copy(),
            translation=self.translation[index].copy(),
            face=self.face[index].copy(),
            vad=self.vad[index].copy(),
            state=ConversationState(int(self.state[index])),
        )

    def frames(self) -> Iterable[MotionFrame]:
        return (self.frame(i) for i in range(self.num_frames))

    @classmethod
    def from_frames(
        cls, frames: Sequence[MotionFrame], fps: float = FPS, metadata: dict[str, Any] | None = None
    ) -> MotionClip:
        return cls(
            pose=np.stack([f.pose for f in frames]).astype(np.float32)
            if frames
            else np.zeros((0, NUM_JOINTS, 3), np.float32),
            translation=np.stack([f.translation for f in frames]).astype(np.float32)
            if frames
            else np.zeros((0, 3), np.float32),
            face=np.stack([f.face for f in frames]).astype(np.float32)
            if frames
            else np.zeros((0, NUM_BLENDSHAPES), np.float32),
            vad=np.stack([f.vad for f in frames]).astype(np.float32) if frames else np.zeros((0, 2), np.float32),
            state=np.array([int(f.state) for f in frames], np.int8),
            fps=fps,
            metadata=dict(metadata or {}),
        )

    @classmethod
    def neutral(cls, num_frames: int, fps: float = FPS) -> MotionClip:
        return cls(
            pose=np.zeros((num_frames, NUM_JOINTS, 3), np.float32),
            translation=np.zeros((num_frames, 3), np.float32),
            face=np.zeros((num_frames, NUM_BLENDSHAPES), np.float32),
            vad=np.zeros((num_frames, 2), np.float32),
            state=np.zeros(num_frames, np.int8),
            fps=fps,
        )
