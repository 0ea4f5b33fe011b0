"""How well the robot's read-back follows the commands: lag and tracking error.

The lag is the delay that best aligns the read-back with the commands (the least RMS head-angle
error over delays up to ``MAX_LAG_S``); the tracking error is that residual, in degrees, and in
millimetres for the head's position. Both come from the histories the backend keeps: the commands
with the time they left, the read-backs with the time they arrived.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from convodrive.backends.reachy.pose import ANTENNAS, BODY, HEAD_ANGLES, X, Z

MAX_LAG_S = 0.5
LAG_STEP_S = 0.005


def follow_figures(
    commands: Sequence[tuple[float, np.ndarray]], readback: Sequence[tuple[float, np.ndarray]]
) -> dict[str, Any]:
    """Lag and residuals of ``readback`` against ``commands`` (both (time, vector), time-ordered)."""
    if len(commands) < 10 or len(readback) < 10:
        return {"lag_ms": None, "samples": 0}
    tc = np.array([t for t, _ in commands])
    c = np.stack([v for _, v in commands])
    r_all = [(t, v) for t, v in readback if tc[0] + MAX_LAG_S <= t <= tc[-1] + LAG_STEP_S]
    if len(r_all) < 10:
        return {"lag_ms": None, "samples": len(r_all)}
    tr = np.array([t for t, _ in r_all])
    r = np.stack([v for _, v in r_all])

    def held(delay: float) -> np.ndarray:
        """The command in force at each read-back time minus ``delay`` (commands are steps)."""
        idx = np.clip(np.searchsorted(tc, tr - delay, side="right") - 1, 0, len(tc) - 1)
        return c[idx]

    lags = np.arange(0.0, MAX_LAG_S + 1e-9, LAG_STEP_S)
    rms = [float(np.sqrt(np.mean((held(d)[:, HEAD_ANGLES] - r[:, HEAD_ANGLES]) ** 2))) for d in lags]
    best = int(np.argmin(rms))
    error = held(lags[best]) - r
    head_deg = np.degrees(np.abs(error[:, HEAD_ANGLES]))
    return {
        "lag_ms": round(1e3 * float(lags[best]), 1),
        "samples": int(len(tr)),
        "head_rms_deg": round(math.degrees(rms[best]), 3),
        "head_p99_deg": round(float(np.percentile(head_deg.max(axis=1), 99)), 3),
        "position_rms_mm": round(1e3 * float(np.sqrt(np.mean(error[:, X : Z + 1] ** 2))), 3),
        "body_rms_deg": round(math.degrees(float(np.sqrt(np.mean(error[:, BODY] ** 2)))), 3),
        "antenna_rms_rad": round(float(np.sqrt(np.mean(error[:, ANTENNAS] ** 2))), 4),
    }


def speeds_by_state(
    times: np.ndarray, vectors: np.ndarray, states: np.ndarray, names: Mapping[int, str]
) -> dict[str, dict[str, float]]:
    """Mean speed of the head (deg/s, its roll, pitch and yaw summed) and of the antennas (rad/s,
    both summed) in each conversation state: the path travelled between consecutive samples of
    the same state over the time they span (jitter in the samples' times cancels out). A state
    not in ``names`` (an ease) is left out."""
    if len(times) < 2:
        return {}
    dt = np.diff(times)
    head = np.degrees(np.abs(np.diff(vectors[:, HEAD_ANGLES], axis=0))).sum(axis=1)
    antennas = np.abs(np.diff(vectors[:, ANTENNAS], axis=0)).sum(axis=1)
    same = states[1:] == states[:-1]
    out = {}
    for code, name in names.items():
        mask = same & (states[1:] == code)
        span = float(dt[mask].sum())
        if mask.sum() >= 5 and span > 0:
            out[name] = {
                "head_deg_s": round(float(head[mask].sum()) / span, 3),
                "antennas_rad_s": round(float(antennas[mask].sum()) / span, 4),
                "seconds": round(span, 2),
            }
    return out
