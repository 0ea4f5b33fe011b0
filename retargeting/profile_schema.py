"""What a robot profile may say, and the objects it is parsed into (``profile.RobotProfile`` holds them).

Schema (per joint under ``joints:``)::

    source: TERM            # or  sum: [TERM, ...]; neither for a joint listed under ik.joints
    gain: 1.0               # value = offset + direction * gain * sum(weight * map(term))
    offset: 0.0
    direction: 1            # +1 or -1
    limits: [lo, hi]        # required
    max_velocity: inf       # units/s
    max_acceleration: inf   # units/s^2
    neutral: 0.0            # clamped into the limits
    units: rad              # rad | norm | m
    smoothing: {filter: one_euro, min_cutoff: 1.5, beta: 0.3, d_cutoff: 1.0}
               # or {filter: critical, time_constant: 0.05}, or none

    TERM: {rotation: JOINT | [JOINT, ...], euler: ZXY, axis: 0..2 | X | Y | Z}
        | {blendshape: ARKIT_NAME}
        | {translation: 0..2 | X | Y | Z}
      each with optional  weight: 1.0  and  map: [[x0, y0], [x1, y1], ...]
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

AXES = "XYZ"
UNITS = ("rad", "norm", "m")
FILTERS = ("one_euro", "critical", "none")
OPAQUE_KEYS = ("backends", "generator")
TOP_KEYS = ("name", "description", "model", "defaults", "joints", "ik", *OPAQUE_KEYS)
JOINT_KEYS = (
    "source",
    "sum",
    "gain",
    "offset",
    "direction",
    "limits",
    "max_velocity",
    "max_acceleration",
    "neutral",
    "units",
    "smoothing",
)
TERM_KEYS = ("rotation", "blendshape", "translation", "euler", "axis", "weight", "map")
MAX_MAGNITUDE = 1e6
"""Largest size of any number in a profile: anything bigger is a typo, and would overflow."""
SMOOTHING_DEFAULT: dict[str, Any] = {"filter": "one_euro", "min_cutoff": 1.5, "beta": 0.3, "d_cutoff": 1.0}


@dataclasses.dataclass(frozen=True)
class Term:
    """One input of a joint: a canonical quantity, an optional piecewise-linear map, a weight."""

    kind: str  # "rotation" | "blendshape" | "translation"
    chain: tuple[str, ...] = ()  # rotation: canonical joints whose local rotations are composed
    euler: str = "XYZ"
    axis: int = 0  # rotation: index into ``euler``; translation: coordinate
    channel: str = ""  # blendshape name
    weight: float = 1.0
    map_x: tuple[float, ...] | None = None
    map_y: tuple[float, ...] | None = None


@dataclasses.dataclass(frozen=True)
class Smoothing:
    filter: str = "one_euro"
    min_cutoff: float = 1.5
    beta: float = 0.3
    d_cutoff: float = 1.0
    time_constant: float = 0.05


@dataclasses.dataclass(frozen=True)
class JointMap:
    name: str
    terms: tuple[Term, ...]
    gain: float
    offset: float
    direction: float
    lower: float
    upper: float
    max_velocity: float
    max_acceleration: float
    neutral: float
    units: str
    smoothing: Smoothing


@dataclasses.dataclass(frozen=True)
class IKTask:
    """Move a robot frame to where a canonical joint is, relative to an anchor pair."""

    frame: str
    frame_type: str
    canonical: str
    anchor_canonical: str
    anchor_body: str
    position_cost: float
    orientation_cost: float


@dataclasses.dataclass(frozen=True)
class IKConfig:
    joints: tuple[str, ...]
    root_canonical: str
    root_body: str
    tasks: tuple[IKTask, ...]
    axes: np.ndarray  # (3, 3): robot vector = axes @ canonical vector
    scale: float
    posture_cost: float
    iterations: int
    damping: float
    solver: str
