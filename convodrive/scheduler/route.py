"""A route: one backend and the retargeter that turns canonical motion into its joint values."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from convodrive.backends.base import Backend
from convodrive.motion.clip import MotionFrame

Retarget = Callable[[MotionFrame], np.ndarray]


@dataclasses.dataclass
class Route:
    backend: Backend
    retarget: Retarget | None = None
    """None for backends that take canonical motion only; then ``values`` is empty."""
    retarget_key: str = ""
    """Routes with equal keys share one retargeting per frame."""
