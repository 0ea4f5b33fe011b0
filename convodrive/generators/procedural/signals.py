"""Chunk-invariant building blocks: seeded per-frame noise and filters that carry their state.

Every value here depends on the absolute frame index and the seed only, never on how frames were
batched, so streaming in 3-frame steps and generating a whole clip at once give identical motion.
"""

from __future__ import annotations

import math

import numpy as np

from convodrive import FPS
from convodrive.plumbing.lazy_import import scipy_signal

_BLOCK = 256


class FrameNoise:
    """Random numbers indexed by absolute frame: block b of stream s is drawn from (seed, s, b)."""

    def __init__(self, seed: int, stream: int, dims: int = 1, kind: str = "uniform") -> None:
        self.seed, self.stream, self.dims, self.kind = int(seed), stream, dims, kind
        self._cache: dict[int, np.ndarray] = {}

    def _block(self, b: int) -> np.ndarray:
        if b not in self._cache:
            rng = np.random.default_rng([self.seed & 0xFFFFFFFF, self.stream, b])
            size = (_BLOCK, self.dims)
            self._cache = {b: rng.random(size) if self.kind == "uniform" else rng.standard_normal(size)}
        return self._cache[b]

    def take(self, first: int, n: int) -> np.ndarray:
        """(n, dims) values for frames ``first .. first+n-1``."""
        out = np.empty((n, self.dims))
        k = first
        while k < first + n:
            b, off = divmod(k, _BLOCK)
            m = min(_BLOCK - off, first + n - k)
            out[k - first : k - first + m] = self._block(b)[off : off + m]
            k += m
        return out


def alpha(tau: float) -> float:
    """One-pole smoothing coefficient for time constant ``tau`` seconds at 30 fps."""
    return 1.0 - math.exp(-1.0 / (FPS * max(tau, 1e-6)))


class Filter:
    """An IIR filter along time (axis 0) that keeps its state between calls."""

    def __init__(self, b: list[float], a: list[float], dims: int = 1) -> None:
        self.b, self.a = np.asarray(b, float), np.asarray(a, float)
        self.zi = np.zeros((max(len(self.a), len(self.b)) - 1, dims))

    def settle(self, value: np.ndarray) -> Filter:
        """Start as if ``value`` had always been the input: the output begins there, not at zero."""
        self.zi = scipy_signal().lfilter_zi(self.b, self.a)[:, None] * np.asarray(value, float).reshape(1, -1)
        return self

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x2 = x.reshape(len(x), -1).astype(np.float64)
        if len(x2) == 0:
            return x2.reshape(x.shape)
        y, self.zi = scipy_signal().lfilter(self.b, self.a, x2, axis=0, zi=self.zi)
        return y.reshape(x.shape)


def smoother(tau: float, dims: int = 1) -> Filter:
    """Critically damped second-order low-pass (two one-poles): eases in and out, no overshoot."""
    k = alpha(tau)
    return Filter([k * k], [1.0, -2.0 * (1.0 - k), (1.0 - k) ** 2], dims)


def one_pole(tau: float, dims: int = 1) -> Filter:
    k = alpha(tau)
    return Filter([k], [1.0, -(1.0 - k)], dims)


def bump(tau: float, dims: int = 1) -> Filter:
    """Impulse response t * exp(-t / tau), normalised to peak 1 at t = tau: a nod, a brow raise."""
    r = math.exp(-1.0 / (FPS * tau))
    m = FPS * tau
    peak = m * r ** (m - 1.0)  # h[n] = n r^(n-1) peaks at n = FPS tau
    return Filter([0.0, 1.0 / peak], [1.0, -2.0 * r, r * r], dims)


class AttackRelease:
    """A one-pole follower that rises with time constant ``attack`` and falls with ``release``
    (seconds): a jaw that opens smoothly and shuts promptly when the voice stops."""

    def __init__(self, attack: float, release: float) -> None:
        self.up, self.down = alpha(attack), alpha(release)
        self.y = 0.0

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = np.empty(len(x))
        y, up, down = self.y, self.up, self.down
        for i, v in enumerate(x.tolist()):
            y += (up if v > y else down) * (v - y)
            out[i] = y
        self.y = y
        return out
