"""Position, velocity and acceleration limits: the last stage before a value leaves the retargeter.

The limiter moves each joint toward its (clamped) target no faster than ``max_velocity``, changes
speed by at most ``max_acceleration * dt`` per step, and slows down early enough to stop at the
target (speed at most sqrt(2 a d) at distance d), so it does not overshoot. Positions are clamped
to the limits last, so no output ever leaves them.
"""

from __future__ import annotations

import numpy as np

from convodrive.motion.targets import TargetSpec


class MotionLimiter:
    """Stateful per-joint limiter; the first frame after ``reset`` is taken as is (clamped)."""

    def __init__(self, spec: TargetSpec) -> None:
        self.lower = np.asarray(spec.lower, np.float64)
        self.upper = np.asarray(spec.upper, np.float64)
        self.vmax = np.asarray(spec.max_velocity, np.float64)
        self.amax = np.asarray(spec.max_acceleration, np.float64)
        self._amax2 = 2.0 * np.minimum(self.amax, 1e300)  # finite, so that 0 distance never gives inf * 0
        self.reset()

    def reset(self, position: np.ndarray | None = None) -> None:
        self.x = None if position is None else np.clip(np.asarray(position, np.float64), self.lower, self.upper)
        self.v = np.zeros_like(self.lower)

    def __call__(self, target: np.ndarray, dt: float) -> np.ndarray:
        target = np.minimum(np.maximum(target, self.lower), self.upper)
        if self.x is None:
            self.x = target.copy()
            return target
        err = target - self.x
        dist = np.abs(err)
        # Fastest speed toward the target that can still stop there: one step, vmax, braking.
        speed = np.minimum(np.minimum(dist / dt, self.vmax), np.sqrt(self._amax2 * dist))
        v_want = np.copysign(speed, err)
        dv_max = self.amax * dt
        v = self.v + np.minimum(np.maximum(v_want - self.v, -dv_max), dv_max)
        v = np.minimum(np.maximum(v, -self.vmax), self.vmax)
        x = np.minimum(np.maximum(self.x + v * dt, self.lower), self.upper)
        self.v = (x - self.x) / dt
        self.x = x
        return x
