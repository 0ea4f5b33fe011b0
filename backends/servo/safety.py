"""The servo backends' second guard: limits, rate limits, easing, and the raw-unit conversion.

The retargeter already keeps frames inside the profile's limits; this layer makes sure that no
command outside them ever reaches a servo, whatever arrives. A frame with a value beyond the
limits (or not finite) is refused whole, small overshoots are clamped, velocity and acceleration
are limited against the last command, and the raw value (Dynamixel ticks, Maestro quarter
microseconds) is clipped once more to the calibrated raw range before it is sent.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from convodrive.motion.targets import TargetSpec

TOLERANCE = 1e-6
"""Overshoot (in joint units) that is clamped rather than refused: float noise, not a bad frame."""


@dataclasses.dataclass(frozen=True)
class RawMap:
    """Joint value -> raw servo unit per joint: ``raw = zero + scale * value``, kept in ``[low, high]``.

    ``scale`` carries the direction (negative = reversed). Raw limits come from calibration and are
    the servo's physical range; ``joint_bounds`` turns them back into joint units.
    """

    zero: np.ndarray
    scale: np.ndarray
    low: np.ndarray
    high: np.ndarray

    def __post_init__(self) -> None:
        if np.any(self.scale == 0) or np.any(self.low > self.high):
            raise ValueError("RawMap needs a non-zero scale and low <= high")

    def to_raw(self, values: np.ndarray) -> np.ndarray:
        raw = np.rint(self.zero + self.scale * values)
        return np.clip(raw, self.low, self.high).astype(np.int64)

    def to_joint(self, raw: np.ndarray) -> np.ndarray:
        return (np.asarray(raw, dtype=float) - self.zero) / self.scale

    def joint_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        a, b = self.to_joint(self.low), self.to_joint(self.high)
        return np.minimum(a, b), np.maximum(a, b)


class Refused(ValueError):
    """A frame the guard will not send; the message says which joint and why."""


class SafetyGuard:
    """Limits every command against the spec, the calibration and the last command sent.

    Joint bounds are the intersection of the spec limits and the calibrated raw range; the raw
    value is clipped to that range once more after rounding.
    """

    def __init__(self, spec: TargetSpec, raw_map: RawMap) -> None:
        self.spec = spec
        self.raw_map = raw_map
        raw_lo, raw_hi = raw_map.joint_bounds()
        self.lower = np.maximum(spec.lower, raw_lo)
        self.upper = np.minimum(spec.upper, raw_hi)
        empty = self.lower > self.upper
        if np.any(empty):
            bad = ", ".join(spec.names[i] for i in np.flatnonzero(empty))
            raise ValueError(f"calibrated range does not overlap the profile limits for {bad}")
        self.max_velocity = np.asarray(spec.max_velocity, dtype=float)
        self.max_acceleration = np.asarray(spec.max_acceleration, dtype=float)
        self.neutral = np.clip(spec.neutral, self.lower, self.upper)
        self.last: np.ndarray | None = None
        self.velocity = np.zeros(len(spec.names))
        self.refused = 0
        self.clamped = 0

    def check(self, values: np.ndarray) -> np.ndarray:
        """Return the frame as floats if it may be sent; raise ``Refused`` if not."""
        values = np.asarray(values, dtype=float)
        if values.shape != (len(self.spec.names),):
            self.refused += 1
            raise Refused(f"frame has {values.size} values, {self.spec.name} has {len(self.spec.names)} joints")
        bad = ~np.isfinite(values) | (values < self.spec.lower - TOLERANCE) | (values > self.spec.upper + TOLERANCE)
        if np.any(bad):
            self.refused += 1
            i = int(np.flatnonzero(bad)[0])
            raise Refused(
                f"{self.spec.names[i]}={values[i]:.4g} outside [{self.spec.lower[i]:.4g}, {self.spec.upper[i]:.4g}]"
            )
        return values

    def limit(self, target: np.ndarray, dt: float) -> np.ndarray:
        """Clamp to the bounds, then limit velocity and acceleration against the last command."""
        target = np.asarray(target, dtype=float)
        clipped = np.clip(target, self.lower, self.upper)
        self.clamped += int(np.any(clipped != target))
        if self.last is None or dt <= 0:
            command = clipped
            velocity = np.zeros_like(clipped)
        else:
            velocity = (clipped - self.last) / dt
            velocity = np.clip(velocity, -self.max_velocity, self.max_velocity)
            dv = self.max_acceleration * dt
            velocity = np.clip(velocity, self.velocity - dv, self.velocity + dv)
            command = np.where(np.isfinite(velocity * dt), self.last + velocity * dt, clipped)
            # Exact where nothing limited the step, so an in-limits trajectory passes unchanged.
            command = np.where(velocity == (clipped - self.last) / dt, clipped, command)
            command = np.clip(command, self.lower, self.upper)
        self.velocity = velocity
        self.last = command
        return command

    def to_raw(self, command: np.ndarray) -> np.ndarray:
        """The raw value for a limited command: always inside the calibrated raw range."""
        raw = self.raw_map.to_raw(command)
        assert np.all((raw >= self.raw_map.low) & (raw <= self.raw_map.high))
        return raw

    def reset(self, current: np.ndarray) -> None:
        """Start from a measured pose (after open or a reconnect), at rest."""
        self.last = np.clip(np.asarray(current, dtype=float), self.lower, self.upper)
        self.velocity = np.zeros(len(self.spec.names))


@dataclasses.dataclass
class Ease:
    """A smooth move from ``start`` to ``goal`` over ``duration`` seconds (zero velocity at both ends)."""

    start: np.ndarray
    goal: np.ndarray
    duration: float
    t0: float = dataclasses.field(default_factory=time.monotonic)

    def at(self, now: float) -> np.ndarray:
        u = 1.0 if self.duration <= 0 else min(1.0, max(0.0, (now - self.t0) / self.duration))
        s = 0.5 - 0.5 * math.cos(math.pi * u)
        return self.start + (self.goal - self.start) * s

    def done(self, now: float) -> bool:
        return now - self.t0 >= self.duration


class Watchdog:
    """Tells the backend to ease to neutral when frames stop for ``timeout`` seconds."""

    def __init__(self, timeout: float = 0.5) -> None:
        self.timeout = timeout
        self.last_frame = time.monotonic()
        self.tripped = 0

    def feed(self) -> None:
        self.last_frame = time.monotonic()

    def expired(self, now: float | None = None) -> bool:
        return (now if now is not None else time.monotonic()) - self.last_frame > self.timeout


def sub_spec(spec: TargetSpec, names: list[str]) -> TargetSpec:
    """The spec restricted to the joints a backend drives."""
    idx = [spec.index[n] for n in names]
    return TargetSpec(
        spec.name,
        tuple(names),
        spec.lower[idx],
        spec.upper[idx],
        spec.neutral[idx],
        spec.max_velocity[idx],
        spec.max_acceleration[idx],
        tuple(spec.units[i] for i in idx),
        spec.model,
    )
