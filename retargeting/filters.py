"""Smoothing filters, one value per joint, stepped once per frame.

One Euro (Casiez et al. 2012) smooths jitter at rest yet follows fast moves: its cutoff rises with
speed. The critically damped filter is a second-order follower that never overshoots, for joints
that must stay crisp (jaw, lids): it is integrated exactly, so it is stable at any time constant.
``Smoother`` runs each joint through the filter its profile names.
"""

from __future__ import annotations

import numpy as np

from convodrive.retargeting.profile_schema import Smoothing


class OneEuroFilter:
    """Vectorised One Euro filter over J channels.

    As in the reference implementation, speed is estimated from the raw samples (then low-passed
    at ``d_cutoff``), and the smoothing factor for cutoff f is f / (f + 1 / (2 pi dt)).
    """

    def __init__(
        self, min_cutoff: np.ndarray | float, beta: np.ndarray | float, d_cutoff: np.ndarray | float = 1.0
    ) -> None:
        self.min_cutoff = np.asarray(min_cutoff, np.float64)
        self.beta = np.asarray(beta, np.float64)
        self.d_cutoff = np.asarray(d_cutoff, np.float64)
        self.reset()

    def reset(self) -> None:
        self.x: np.ndarray | None = None
        self.raw = self.dx = 0.0

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        if self.x is None:
            self.x = np.array(x, np.float64)
            self.raw = self.x.copy()
            self.dx = np.zeros_like(self.x)
            return self.x.copy()
        k = 1.0 / (2.0 * np.pi * dt)
        self.dx = self.dx + self.d_cutoff / (self.d_cutoff + k) * ((x - self.raw) / dt - self.dx)
        self.raw = np.array(x, np.float64)
        cutoff = self.min_cutoff + self.beta * np.abs(self.dx)
        self.x = self.x + cutoff / (cutoff + k) * (x - self.x)
        return self.x


class CriticallyDampedFilter:
    """Second-order follower x'' = w^2 (target - x) - 2 w x', solved exactly over each step."""

    def __init__(self, time_constant: np.ndarray | float) -> None:
        self.omega = 1.0 / np.asarray(time_constant, np.float64)
        self.reset()

    def reset(self) -> None:
        self.x: np.ndarray | None = None
        self.v = 0.0

    def __call__(self, target: np.ndarray, dt: float) -> np.ndarray:
        if self.x is None:
            self.x = np.array(target, np.float64)
            self.v = np.zeros_like(self.x)
            return self.x.copy()
        w = self.omega
        e0 = self.x - target
        c = self.v + w * e0
        decay = np.exp(-w * dt)
        self.x = target + (e0 + c * dt) * decay
        self.v = (self.v - w * c * dt) * decay
        return self.x


class Smoother:
    """Per-joint smoothing as a profile declares it (one_euro, critical or none)."""

    def __init__(self, settings: list[Smoothing]) -> None:
        kinds = np.array([s.filter for s in settings])
        self.euro = np.flatnonzero(kinds == "one_euro")
        self.crit = np.flatnonzero(kinds == "critical")
        self.one_euro = OneEuroFilter(
            [settings[i].min_cutoff for i in self.euro],
            [settings[i].beta for i in self.euro],
            [settings[i].d_cutoff for i in self.euro],
        )
        self.critical = CriticallyDampedFilter([settings[i].time_constant for i in self.crit])

    def reset(self) -> None:
        self.one_euro.reset()
        self.critical.reset()

    def batch(self, x: np.ndarray, dt: float) -> np.ndarray:
        """A whole (T, J) sequence from fresh state, as repeated calls would give."""
        out = np.array(x, np.float64)
        if len(out) and self.euro.size:
            f = self.one_euro
            out[:, self.euro] = one_euro_batch(out[:, self.euro], f.min_cutoff, f.beta, f.d_cutoff, dt)
        if len(out) and self.crit.size:
            out[:, self.crit] = critically_damped_batch(out[:, self.crit], 1.0 / self.critical.omega, dt)
        return out

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        out = np.array(x, np.float64)
        if self.euro.size:
            out[self.euro] = self.one_euro(out[self.euro], dt)
        if self.crit.size:
            out[self.crit] = self.critical(out[self.crit], dt)
        return out


def _groups(values: np.ndarray) -> list[tuple[float, np.ndarray]]:
    """Columns sharing a parameter value, so each group is one linear filter."""
    return [(float(v), np.flatnonzero(values == v)) for v in np.unique(values)]


def critically_damped_batch(x: np.ndarray, time_constant: np.ndarray, dt: float) -> np.ndarray:
    """:class:`CriticallyDampedFilter` over a whole (T, J) sequence at once (same numbers).

    The exact per-step update is linear and time-invariant: starting at rest on the first sample,
    it is an IIR filter of (x - x[0]), which ``scipy.signal.lfilter`` runs in C.
    """
    from scipy.signal import lfilter, ss2tf

    out = np.empty_like(x)
    for tc, cols in _groups(np.asarray(time_constant, np.float64)):
        w = 1.0 / tc
        d = np.exp(-w * dt)
        a = np.array([[d * (1 + w * dt), d * dt], [-d * w * w * dt, d * (1 - w * dt)]])
        b = np.array([[1 - d * (1 + w * dt)], [d * w * w * dt]])
        c = np.array([[1.0, 0.0]])
        num, den = ss2tf(a, b, c @ a, c @ b)
        x0 = x[:1, cols]
        out[:, cols] = lfilter(num[0], den, x[:, cols] - x0, axis=0) + x0
    return out


def one_euro_batch(
    x: np.ndarray, min_cutoff: np.ndarray, beta: np.ndarray, d_cutoff: np.ndarray, dt: float
) -> np.ndarray:
    """:class:`OneEuroFilter` over a whole (T, J) sequence: the speed estimate is a linear filter
    (vectorised); only the final, speed-dependent smoothing is a loop over time."""
    from scipy.signal import lfilter

    k = 1.0 / (2.0 * np.pi * dt)
    speed = np.zeros_like(x)
    raw_speed = np.zeros_like(x)
    raw_speed[1:] = np.diff(x, axis=0) / dt
    for dc, cols in _groups(np.asarray(d_cutoff, np.float64)):
        a = dc / (dc + k)
        speed[:, cols] = lfilter([a], [1.0, a - 1.0], raw_speed[:, cols], axis=0)
    cutoff = min_cutoff + beta * np.abs(speed)
    alpha = cutoff / (cutoff + k)
    out = np.empty_like(x)
    prev = out[0] = x[0]
    for t in range(1, len(x)):
        prev = out[t] = prev + alpha[t] * (x[t] - prev)
    return out
