"""Reachy Mini's command space and the limits the backend itself enforces.

A command is nine numbers (``FIELDS``): the head's position in metres and its roll, pitch and yaw
in radians in the daemon's world frame (x forward, y left, z up; +pitch nose down, +yaw toward
the robot's left), the body's yaw, and the two antennas. The daemon's pose is a 4x4 matrix with
extrinsic xyz Euler angles (R = Rz(yaw) Ry(pitch) Rx(roll)), independent of the body's yaw.

The daemon drops a pose its IK cannot reach instead of clamping it (the head then stays where it
was), so every command is clamped here first, to limits inside what the robot reaches
(../shared/reference/REACHY_MINI.md, "Limits"): pitch and roll +-40 deg, the head's yaw within
60 deg of the body's, the body within +-155 deg and the head within +-175 deg (the read-back
breaks across +-180), z -25..+20 mm
and the antennas +-3.0 rad.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

FIELDS = ("x", "y", "z", "roll", "pitch", "yaw", "body_yaw", "antenna_right", "antenna_left")
X, Y, Z, ROLL, PITCH, YAW, BODY, ANT_R, ANT_L = range(len(FIELDS))
HEAD_ANGLES = slice(ROLL, YAW + 1)
ANTENNAS = slice(ANT_R, ANT_L + 1)
NEUTRAL_ANTENNAS = (-0.1745, 0.1745)
"""The daemon's neutral antennas (right, left), 10 deg outward."""


@dataclasses.dataclass(frozen=True)
class Limits:
    """The backend's own limits, in metres and radians."""

    xy: float = 0.015
    z_low: float = -0.025
    z_high: float = 0.020
    roll: float = math.radians(40.0)
    pitch: float = math.radians(40.0)
    head_to_body: float = math.radians(60.0)
    body: float = math.radians(155.0)
    yaw: float = math.radians(175.0)
    """The head's world yaw: past +-180 the daemon's read-back (its FK) breaks until it restarts."""
    antenna: float = 3.0

    def clamp(self, command: np.ndarray) -> np.ndarray:
        """``command`` inside the limits; the head's yaw is clamped relative to the clamped body."""
        out = np.array(command, dtype=float)
        out[[X, Y]] = np.clip(out[[X, Y]], -self.xy, self.xy)
        out[Z] = np.clip(out[Z], self.z_low, self.z_high)
        out[ROLL] = np.clip(out[ROLL], -self.roll, self.roll)
        out[PITCH] = np.clip(out[PITCH], -self.pitch, self.pitch)
        out[BODY] = np.clip(out[BODY], -self.body, self.body)
        out[YAW] = out[BODY] + np.clip(out[YAW] - out[BODY], -self.head_to_body, self.head_to_body)
        out[YAW] = np.clip(out[YAW], -self.yaw, self.yaw)
        out[ANTENNAS] = np.clip(out[ANTENNAS], -self.antenna, self.antenna)
        return out

    def within(self, command: np.ndarray, tolerance: float = 1e-9) -> bool:
        """True when ``command`` needs no clamping (up to ``tolerance``)."""
        return bool(np.all(np.abs(self.clamp(command) - command) <= tolerance))


def neutral() -> np.ndarray:
    """The neutral command: head at its origin, body straight, antennas at the daemon's neutral."""
    out = np.zeros(len(FIELDS))
    out[ANTENNAS] = NEUTRAL_ANTENNAS
    return out


def head_matrix(command: np.ndarray) -> np.ndarray:
    """The 4x4 head pose the daemon takes for ``command`` (reachy_mini.utils.create_head_pose)."""
    roll, pitch, yaw = command[HEAD_ANGLES]
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    pose = np.eye(4)
    pose[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    pose[:3, 3] = command[[X, Y, Z]]
    return pose


def head_from_matrix(pose: np.ndarray) -> np.ndarray:
    """(x, y, z, roll, pitch, yaw) of a 4x4 head pose: the inverse of ``head_matrix``."""
    r = np.asarray(pose, dtype=float)
    pitch = -math.asin(float(np.clip(r[2, 0], -1.0, 1.0)))
    roll = math.atan2(r[2, 1], r[2, 2])
    yaw = math.atan2(r[1, 0], r[0, 0])
    return np.array([r[0, 3], r[1, 3], r[2, 3], roll, pitch, yaw])


def min_jerk(start: np.ndarray, end: np.ndarray, s: float) -> np.ndarray:
    """The point a fraction ``s`` (0..1) of the way along a minimum-jerk ease from start to end."""
    s = min(max(s, 0.0), 1.0)
    return start + (end - start) * (10 * s**3 - 15 * s**4 + 6 * s**5)
