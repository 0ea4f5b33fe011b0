"""Smoothing filters, one value per joint, stepped once per frame.

One Euro (Casiez et al. 2012) smooths jitter at rest yet follows fast moves: its cutoff rises with
speed. The critically damped filter is a second-order follower that never overshoots, for joints
that must stay crisp (jaw, lids): it is integrated exactly, so it is stable at any time constant.
``Smoother`` runs each joint through the filter its profile names.
"""

from __future__ import annotations

import numpy as np

from convodrive.retargeting.profile import Smoothing


def _alpha(cutoff: np.ndarray, dt: float) -> np.ndarray:
    tau = 1.0 / (2.0 * np.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """Vectorised One Euro filter over J channels."""

    def __init__(self, min_cutoff: np.ndarray | float, beta: np.ndarray | float, d_cutoff: np.ndarray | float = 1.0) -> None:
        self.min_cutoff = np.asarray(min_cutoff, np.float64)
        self.beta = np.asarray(beta, np.float64)
        self.d_cutoff = np.asarray(d_cutoff, np.float64)
        self.reset()

    def reset(self) -> None:
        self.x: np.ndarray | None = None
        self.dx = 0.0

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        if self.x is None:
            self.x = np.array(x, np.float64)
            self.dx = np.zeros_like(self.x)
            return self.x.copy()
        a_d = _alpha(self.d_cutoff, dt)
        self.dx = self.dx + a_d * ((x - self.x) / dt - self.dx)
        a = _alpha(self.min_cutoff + self.beta * np.abs(self.dx), dt)
        self.x = self.x + a * (x - self.x)
        return self.x.copy()


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
        return self.x.copy()


class Smoother:
    """Per-joint smoothing as a profile declares it (one_euro, critical or none)."""

    def __init__(self, settings: list[Smoothing]) -> None:
        kinds = np.array([s.filter for s in settings])
        self.euro = np.flatnonzero(kinds == "one_euro")
        self.crit = np.flatnonzero(kinds == "critical")
        self.one_euro = OneEuroFilter([settings[i].min_cutoff for i in self.euro], [settings[i].beta for i in self.euro],
                                      [settings[i].d_cutoff for i in self.euro])
        self.critical = CriticallyDampedFilter([settings[i].time_constant for i in self.crit])

    def reset(self) -> None:
        self.one_euro.reset()
        self.critical.reset()

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        out = np.array(x, np.float64)
        if self.euro.size:
            out[self.euro] = self.one_euro(out[self.euro], dt)
        if self.crit.size:
            out[self.crit] = self.critical(out[self.crit], dt)
        return out
