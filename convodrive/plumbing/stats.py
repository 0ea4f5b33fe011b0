"""Latency figures: exact percentiles of what was kept, and a histogram of milliseconds in bounded
memory, however long the run."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def percentiles(values: Iterable[float], scale: float = 1.0, digits: int = 3) -> dict[str, float] | None:
    """p50, p99 (NumPy's linear interpolation) and max of ``values`` times ``scale``; None when empty."""
    arr = np.fromiter(values, np.float64) * scale
    if not arr.size:
        return None
    return {
        "p50": round(float(np.percentile(arr, 50)), digits),
        "p99": round(float(np.percentile(arr, 99)), digits),
        "max": round(float(arr.max()), digits),
    }


class Histogram:
    """Counts values (ms) in ``step``-wide bins from ``low`` to ``high``; beyond are clamped to the
    ends but ``min``/``max`` stay exact. Percentiles are good to one bin."""

    def __init__(self, low: float = -1000.0, high: float = 2000.0, step: float = 0.1) -> None:
        self.low, self.step = low, step
        self._counts = np.zeros(int(round((high - low) / step)) + 1, np.int64)
        self.count = 0
        self.min = float("inf")
        self.max = float("-inf")
        self._sum = 0.0

    def add(self, value: float) -> None:
        i = int((value - self.low) / self.step)
        self._counts[min(max(i, 0), len(self._counts) - 1)] += 1
        self.count += 1
        self._sum += value
        self.min = min(self.min, value)
        self.max = max(self.max, value)

    def percentile(self, q: float) -> float:
        if not self.count:
            return float("nan")
        rank = q / 100.0 * (self.count - 1)
        i = int(np.searchsorted(np.cumsum(self._counts), rank, side="right"))
        return min(max(self.low + (i + 0.5) * self.step, self.min), self.max)

    def summary(self, digits: int = 1) -> dict[str, float | int] | None:
        """p50, p99, mean, max and count, or None when nothing was added."""
        if not self.count:
            return None
        return {
            "p50": round(self.percentile(50), digits),
            "p99": round(self.percentile(99), digits),
            "mean": round(self._sum / self.count, digits),
            "max": round(self.max, digits),
            "count": self.count,
        }
