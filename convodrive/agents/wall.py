"""Wall time (``time.time()``, what frameworks stamp) to ``time.monotonic()`` (what a session
takes) and back.

The offset between the clocks is read between two monotonic reads close together: read plainly,
a thread switch between the two calls (a GIL hand-over on a busy machine: milliseconds) would
shift every time converted by as much.
"""

from __future__ import annotations

import time

TRIES = 8
TIGHT = 1e-4
"""Seconds: a bracket this short is as close as the clocks can be read together."""


def wall_minus_mono() -> float:
    """``time.time() - time.monotonic()`` at one instant."""
    best = (float("inf"), 0.0)
    for _ in range(TRIES):
        before = time.monotonic()
        wall = time.time()
        after = time.monotonic()
        best = min(best, (after - before, wall - (before + after) / 2))
        if best[0] < TIGHT:
            break
    return best[1]


def to_mono(wall: float) -> float:
    return wall - wall_minus_mono()


def to_wall(mono: float) -> float:
    return mono + wall_minus_mono()
