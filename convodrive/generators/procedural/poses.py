"""Key poses of the arms and hands for conversational gestures, and the relaxed rest pose.

The canonical skeleton rests in a T-pose (Y up, facing +Z, left = +X), so every pose here is the
local rotation that brings a limb from the T-pose to the key pose. Poses are written for the left
arm as intrinsic Euler angles (degrees, ``"XZY"``: forward swing, then lowering about Z, then the
twist/bend about Y) and mirrored for the right arm. Rotating the left upper arm by -72 deg about
Z brings it from +X to pointing down; a negative Y rotation of the elbow bends the forearm forward
(+Z); a negative Z rotation curls the left fingers toward the palm (-Y in the T-pose).
"""

from __future__ import annotations

import numpy as np

from convodrive.motion.rotations import euler_to_axis_angle
from convodrive.motion.skeleton import JOINT_INDEX, NUM_JOINTS

KEY_POSES: tuple[str, ...] = ("rest", "beat", "open_palms", "precision_grip", "pointing")
FINGERS = ("index", "middle", "ring", "pinky", "thumb")

# Left arm: shoulder (forward swing X, lower Z, twist Y), elbow bend (about Y), wrist (X twist: -
# turns the palm up when the forearm points forward; Z: flexion), finger curl per finger (deg).
_LEFT: dict[str, dict] = {
    "rest": dict(
        shoulder=(-12, -74, 0),
        elbow=(0, 0, -62),
        wrist=(10, -5, 0),
        curl=dict(index=15, middle=20, ring=24, pinky=28, thumb=8),
    ),
    "beat": dict(
        shoulder=(-24, -68, 0),
        elbow=(0, 0, -84),
        wrist=(25, -12, 0),
        curl=dict(index=28, middle=34, ring=38, pinky=42, thumb=15),
    ),
    "open_palms": dict(
        shoulder=(-26, -60, -8),
        elbow=(0, 0, -78),
        wrist=(-70, 8, 0),
        curl=dict(index=4, middle=5, ring=6, pinky=8, thumb=0),
    ),
    "precision_grip": dict(
        shoulder=(-28, -66, 0),
        elbow=(0, 0, -96),
        wrist=(5, -10, 0),
        curl=dict(index=42, middle=55, ring=62, pinky=66, thumb=32),
    ),
    "pointing": dict(
        shoulder=(-42, -58, 0),
        elbow=(0, 0, -48),
        wrist=(15, 0, 0),
        curl=dict(index=0, middle=78, ring=82, pinky=84, thumb=35),
    ),
}

ARM_JOINTS: dict[str, list[int]] = {}
for _side in ("left", "right"):
    ARM_JOINTS[_side] = [JOINT_INDEX[f"{_side}_{j}"] for j in ("shoulder", "elbow", "wrist")] + [
        JOINT_INDEX[f"{_side}_{f}{i}"] for f in FINGERS for i in (1, 2, 3)
    ]


def _left_pose(spec: dict) -> np.ndarray:
    """(18, 3) axis-angle of the left shoulder, elbow, wrist and 15 finger joints."""
    rows = [
        np.radians(spec["shoulder"]),
        np.radians(spec["elbow"]),
        np.radians(spec["wrist"]),
    ]
    out = [euler_to_axis_angle(r, "XZY") for r in rows]
    for finger in FINGERS:
        curl = spec["curl"][finger]
        for seg in range(3):
            scale = (1.0, 1.1, 0.8)[seg]
            if finger == "thumb":
                out.append(euler_to_axis_angle(np.radians([0.0, 0.0, -0.6 * curl * scale]), "XZY"))
            else:
                out.append(euler_to_axis_angle(np.radians([0.0, -curl * scale, 0.0]), "XZY"))
    return np.stack(out)


def mirror(aa: np.ndarray) -> np.ndarray:
    """Left-side local rotations to right-side ones: reflect through the X = 0 plane."""
    return aa * np.array([1.0, -1.0, -1.0])


LIBRARY: np.ndarray = np.stack([_left_pose(_LEFT[name]) for name in KEY_POSES])
"""(P, 18, 3) left-arm key poses in ``KEY_POSES`` order; ``mirror`` gives the right arm's."""
LIBRARY_RIGHT: np.ndarray = mirror(LIBRARY)


def rest_variant(shoulder: tuple[float, float, float], elbow: float, wrist: float, curl: float) -> np.ndarray:
    """(18, 3) left-arm rest pose moved by ``shoulder`` (X, Z, Y degrees), a deeper or shallower
    ``elbow`` bend, a ``wrist`` flexion (degrees) and finger curl scaled by ``curl``: the same
    relaxed rest, held a little differently (mirror it for the right arm)."""
    rest = _LEFT["rest"]
    spec = dict(
        shoulder=tuple(a + b for a, b in zip(rest["shoulder"], shoulder)),
        elbow=(rest["elbow"][0], rest["elbow"][1], rest["elbow"][2] - elbow),
        wrist=(rest["wrist"][0], rest["wrist"][1] - wrist, rest["wrist"][2]),
        curl={f: c * curl for f, c in rest["curl"].items()},
    )
    return _left_pose(spec)


def rest_pose() -> np.ndarray:
    """(55, 3) the relaxed conversational pose: arms down, elbows bent, hands in front."""
    pose = np.zeros((NUM_JOINTS, 3))
    pose[ARM_JOINTS["left"]] = LIBRARY[0]
    pose[ARM_JOINTS["right"]] = LIBRARY_RIGHT[0]
    return pose
