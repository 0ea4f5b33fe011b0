"""Target frames: what the retargeter hands to backends, in a target's own joint space.

A ``TargetSpec`` describes a body's joints (names, limits, neutral, units); a ``TargetFrame``
carries one value per joint for one instant, plus the canonical motion it came from, because the
renderer and the recorder speak canonical motion rather than joints.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import numpy as np

from convodrive.motion.clip import MotionFrame

Unit = Literal["rad", "norm", "m"]


@dataclasses.dataclass(frozen=True)
class TargetSpec:
    """A body's joint space. Arrays are (J,) in ``names`` order; ``units`` says what a value means."""

    name: str
    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    neutral: np.ndarray
    max_velocity: np.ndarray  # units per second; inf where unlimited
    max_acceleration: np.ndarray  # units per second squared; inf where unlimited
    units: tuple[Unit, ...]
    model: Path | None = None
    """The body's MJCF, when its profile names one (what a simulator loads)."""

    def __post_init__(self) -> None:
        n = len(self.names)
        for field in ("lower", "upper", "neutral", "max_velocity", "max_acceleration"):
            if np.shape(getattr(self, field)) != (n,):
                raise ValueError(f"TargetSpec.{field} must have shape ({n},)")
        if len(self.units) != n:
            raise ValueError("TargetSpec.units must name one unit per joint")
        if np.any(self.lower > self.upper):
            bad = [self.names[i] for i in np.flatnonzero(self.lower > self.upper)]
            raise ValueError(f"TargetSpec {self.name}: lower limit above upper for {', '.join(bad)}")

    @property
    def index(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.names)}

    def within_limits(self, values: np.ndarray, tolerance: float = 1e-9) -> bool:
        return bool(np.all(values >= self.lower - tolerance) and np.all(values <= self.upper + tolerance))

    @classmethod
    def empty(cls, name: str = "canonical") -> TargetSpec:
        """The spec of a backend that takes canonical motion only (renderer, recorder)."""
        z = np.zeros(0)
        return cls(name, (), z, z, z, z, z, ())


@dataclasses.dataclass(frozen=True)
class TargetFrame:
    """One instant for one body: joint ``values`` in ``spec.names`` order and the motion behind them.

    ``takes`` holds every sample of the motion when a run generates several (``--samples K``);
    joint values always come from the first take, since a body has one pose.
    """

    index: int
    time: float
    values: np.ndarray
    takes: tuple[MotionFrame, ...]
    dispatched: float = 0.0
    """``time.monotonic()`` when the clock sent the frame out (real-time runs; 0 offline): lets a
    backend or the run report measure how long a frame took to reach its body."""

    @property
    def motion(self) -> MotionFrame:
        return self.takes[0]
