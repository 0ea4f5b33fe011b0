"""The mannequin's skull and skin: the head's shape, its colours, and the morph targets of the
skin (the jaw's opening, cheeks, brows, nose and the mouth's corners), all hanging from the
``head`` joint. The features set on it (lips, eyes, lids, nose, ears, brows, hair) are
``mannequin_face``'s.
"""

from __future__ import annotations

import numpy as np

from convodrive.backends.avatar.mesh_build import (
    Part,
    grid_faces,
    orient_outward,
    part,
    rigid_weights,
    smoothstep,
)
from convodrive.motion.skeleton import JOINT_INDEX, NUM_JOINTS, REST_POSITIONS

J = JOINT_INDEX

COLORS: dict[str, tuple[float, float, float]] = {
    "skin": (0.78, 0.575, 0.475),
    "blush": (0.78, 0.49, 0.43),
    "socket": (0.66, 0.48, 0.42),
    "lips": (0.64, 0.33, 0.32),
    "hair": (0.13, 0.085, 0.06),
    "sclera": (0.80, 0.77, 0.73),
    "sclera_edge": (0.66, 0.56, 0.52),
    "iris": (0.26, 0.40, 0.44),
    "iris_inner": (0.45, 0.47, 0.33),
    "limbus": (0.08, 0.11, 0.13),
    "pupil": (0.015, 0.015, 0.02),
    "teeth": (0.90, 0.87, 0.80),
    "mouth": (0.26, 0.07, 0.08),
    "tongue": (0.62, 0.29, 0.30),
    "lash": (0.07, 0.05, 0.04),
}

HEAD_CENTER = np.array([0.0, 1.645, 0.005])
HEAD_RADII = np.array([0.077, 0.115, 0.098])
EYE_RADIUS = 0.0115
EYES = (REST_POSITIONS[J["left_eye_smplhf"]].copy(), REST_POSITIONS[J["right_eye_smplhf"]].copy())
MOUTH_Y = 1.572
MOUTH_HALF_WIDTH = 0.025
JAW_PIVOT = np.array([0.0, 1.60, -0.02])
JAW_OPEN_ANGLE = 0.27
"""Radians the lower face turns about ``JAW_PIVOT`` at ``jawOpen`` = 1. The ``jaw`` joint's
rotation is read as the same opening (``RigPoser.morph_weights``), so joint and channel never
open the mouth twice."""


def _taper(dy: np.ndarray) -> np.ndarray:
    """Narrower toward the jaw: the head's half-width scale at normalised height ``dy``."""
    return 1.0 - 0.13 * np.maximum(-dy, 0.0) ** 1.5


def head_point(d: np.ndarray) -> np.ndarray:
    """Map unit directions to the head surface (an ellipsoid with a tapered jaw, fuller at the back)."""
    dy = d[..., 1]
    back = np.where(d[..., 2] < 0, 1.06, 1.0)
    return HEAD_CENTER + np.stack([d[..., 0] * _taper(dy), dy, d[..., 2] * back], -1) * HEAD_RADII


def surface_z(x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    """The front of the head surface at (x, y), before eye sockets are pressed in."""
    dy = np.clip((np.asarray(y, float) - HEAD_CENTER[1]) / HEAD_RADII[1], -0.999, 0.999)
    c = np.sqrt(1 - dy**2)
    s = np.clip((np.asarray(x, float) - HEAD_CENTER[0]) / (HEAD_RADII[0] * _taper(dy) * c), -0.999, 0.999)
    return HEAD_CENTER[2] + HEAD_RADII[2] * c * np.sqrt(1 - s**2)


def _rotate_x(p: np.ndarray, pivot: np.ndarray, angle: float) -> np.ndarray:
    r = p - pivot
    c, s = np.cos(angle), np.sin(angle)
    return pivot + np.stack([r[:, 0], r[:, 1] * c - r[:, 2] * s, r[:, 1] * s + r[:, 2] * c], 1)


def jaw_delta(p: np.ndarray) -> np.ndarray:
    """Displacement of rest points carried by a fully open jaw."""
    return _rotate_x(p, JAW_PIVOT, JAW_OPEN_ANGLE) - p


def gauss(p: np.ndarray, x: float, y: float, sx: float, sy: float) -> np.ndarray:
    return np.exp(-(((p[:, 0] - x) / sx) ** 2 + ((p[:, 1] - y) / sy) ** 2))


def head_rigid(p: Part) -> Part:
    p.weights = rigid_weights(len(p.verts), J["head"], NUM_JOINTS)
    return p


# ---------------------------------------------------------------------------------------- skull


def head_part() -> Part:
    rows, cols = 44, 56
    v = np.linspace(-1, 1, rows)
    lat = np.sign(v) * np.abs(v) ** 1.15 * (np.pi / 2 - 0.02)
    u = np.linspace(-1, 1, cols, endpoint=False)
    lon = np.sign(u) * np.abs(u) ** 1.5 * np.pi
    d = np.stack(
        [
            np.cos(lat)[:, None] * np.sin(lon),
            np.repeat(np.sin(lat)[:, None], cols, 1),
            np.cos(lat)[:, None] * np.cos(lon),
        ],
        -1,
    ).reshape(-1, 3)
    verts = head_point(d)
    verts = np.concatenate([verts, [head_point(np.array([0, -1.0, 0])), head_point(np.array([0, 1.0, 0]))]])
    # less of an egg: a brow ridge and cheekbones that seat the eyes, a jaw with corners, a chin
    front = smoothstep(0.02, 0.07, verts[:, 2])
    ey = EYES[0][1]
    for sgn in (1, -1):
        verts[:, 2] += 0.006 * gauss(verts, sgn * 0.03, ey + 0.019, 0.024, 0.008) * front
        verts[:, 2] += 0.005 * gauss(verts, sgn * 0.036, ey - 0.024, 0.02, 0.011) * front
        verts[:, 0] += sgn * 0.004 * gauss(verts, sgn * 0.055, ey - 0.03, 0.02, 0.02) * front
        verts[:, 0] += sgn * 0.007 * gauss(verts, sgn * 0.06, 1.56, 0.025, 0.03) * smoothstep(-0.06, 0.0, verts[:, 2])
    verts[:, 2] += 0.005 * gauss(verts, 0.0, 1.535, 0.02, 0.012) * front
    for eye in EYES:  # eye sockets: press the skin in front of each eye back behind the eyeball
        rho = np.hypot((verts[:, 0] - eye[0]) / 1.2, verts[:, 1] - eye[1])
        dent = smoothstep(0.024, 0.0125, rho) * (verts[:, 2] > eye[2] - 0.01)
        verts[:, 2] -= dent * np.maximum(verts[:, 2] - (eye[2] - 0.003), 0.0)
    n = rows * cols
    faces = [grid_faces(rows, cols, wrap=True)]
    bottom, top = np.arange(cols), np.arange(cols) + n - cols
    faces.append(np.stack([bottom, np.roll(bottom, -1), np.full(cols, n)], 1))
    faces.append(np.stack([top, np.roll(top, -1), np.full(cols, n + 1)], 1))
    faces = orient_outward(verts, np.concatenate(faces), HEAD_CENTER)
    p = head_rigid(part("skin", verts, faces, np.zeros(0), skin_colors(verts)))
    p.deltas = _skin_deltas(verts)
    return p


def skin_colors(p: np.ndarray) -> np.ndarray:
    """Skin tinted as faces are: warmer cheeks, nose and ears; shaded sockets and a soft lip line."""
    skin, blush, socket = (np.array(COLORS[k]) for k in ("skin", "blush", "socket"))
    front = smoothstep(HEAD_CENTER[2], HEAD_CENTER[2] + 0.05, p[:, 2])
    cheeks = sum(gauss(p, s * 0.047, 1.59, 0.022, 0.02) for s in (1, -1)) * front
    nose = gauss(p, 0.0, 1.595, 0.012, 0.012) * front
    sockets = sum(gauss(p, e[0], e[1] + 0.004, 0.02, 0.017) for e in EYES) * front
    chin = gauss(p, 0.0, MOUTH_Y - 0.028, 0.03, 0.012) * front
    color = skin + np.clip(0.55 * cheeks + 0.4 * nose + 0.2 * chin, 0, 1)[:, None] * (blush - skin)
    return color + np.clip(0.75 * sockets, 0, 1)[:, None] * (socket - skin)


def _skin_deltas(p: np.ndarray) -> dict[str, np.ndarray]:
    """Morph targets of the face's skin: the lower face rides the jaw; cheeks, chin and the
    corners follow the lips."""
    front = smoothstep(HEAD_CENTER[2] - 0.03, HEAD_CENTER[2] + 0.03, p[:, 2])
    jaw = smoothstep(MOUTH_Y - 0.002, MOUTH_Y - 0.011, p[:, 1]) * front
    out: dict[str, np.ndarray] = {
        "jawOpen": jaw[:, None] * jaw_delta(p),
        "jawForward": jaw[:, None] * [0, 0, 0.008],
        "jawLeft": jaw[:, None] * [0.008, 0, 0],
        "jawRight": jaw[:, None] * [-0.008, 0, 0],
    }
    # everything the lips pull stays within the lower face around the mouth
    window = front * smoothstep(0.062, 0.045, np.abs(p[:, 0])) * smoothstep(MOUTH_Y + 0.02, MOUTH_Y + 0.01, p[:, 1])
    near_mouth = np.exp(-((p[:, 0] / 0.028) ** 2 + ((p[:, 1] - MOUTH_Y) / 0.016) ** 2)) * window
    chin = gauss(p, 0.0, MOUTH_Y - 0.026, 0.022, 0.014) * front
    out["mouthLeft"] = near_mouth[:, None] * [0.006, 0, 0]
    out["mouthRight"] = near_mouth[:, None] * [-0.006, 0, 0]
    out["mouthPucker"] = near_mouth[:, None] * np.stack([-0.3 * p[:, 0], np.zeros(len(p)), np.full(len(p), 0.004)], 1)
    out["mouthShrugLower"] = chin[:, None] * [0, 0.003, 0.002]
    out["mouthRollLower"] = chin[:, None] * [0, 0.001, 0.001]
    out["mouthRollUpper"] = gauss(p, 0.0, MOUTH_Y + 0.01, 0.02, 0.008)[:, None] * front[:, None] * [0, -0.0008, 0.001]
    out["cheekPuff"] = np.zeros((len(p), 3))
    for side, sgn in (("Left", 1.0), ("Right", -1.0)):
        corner = gauss(p, sgn * 0.028, MOUTH_Y + 0.002, 0.013, 0.012) * window
        out[f"mouthSmile{side}"] = corner[:, None] * [sgn * 0.004, 0.006, -0.002]
        out[f"mouthFrown{side}"] = corner[:, None] * [0, -0.005, 0]
        out[f"mouthStretch{side}"] = corner[:, None] * [sgn * 0.005, -0.001, -0.001]
        out[f"mouthDimple{side}"] = corner[:, None] * [sgn * 0.001, 0, -0.003]
        cheek = gauss(p, sgn * 0.045, MOUTH_Y + 0.012, 0.02, 0.02) * front
        out["cheekPuff"] += cheek[:, None] * [sgn * 0.008, 0, 0.004]
        squint = gauss(p, sgn * 0.042, EYES[0][1] - 0.03, 0.02, 0.014) * front
        out[f"cheekSquint{side}"] = squint[:, None] * [0, 0.004, 0.001]
        nose = gauss(p, sgn * 0.012, 1.605, 0.012, 0.012) * front
        out[f"noseSneer{side}"] = nose[:, None] * [0, 0.003, 0.001]
    return out


# ---------------------------------------------------------------------------------------- mouth


def mouth_rig_deltas(p: np.ndarray, up: np.ndarray, lo: np.ndarray, xn: np.ndarray) -> dict[str, np.ndarray]:
    """Morph targets shared by the lips and the mouth's inside.

    ``up``/``lo`` say how much a vertex belongs to the upper or lower lip, ``xn`` is x across the
    mouth normalised to [-1, 1]; lips and the inside then open, round and smile together.
    """
    zero = np.zeros(len(p))
    lo_c, up_c = lo[:, None], up[:, None]
    jaw = jaw_delta(p)
    left, right = smoothstep(0.3, 0.95, xn)[:, None], smoothstep(-0.3, -0.95, xn)[:, None]
    half_l, half_r = smoothstep(-0.2, 0.6, xn)[:, None], smoothstep(0.2, -0.6, xn)[:, None]
    narrow = np.stack([-p[:, 0], zero, zero], 1)
    press = lo_c * [0, 0.0013, 0.0005] + up_c * [0, -0.0013, 0.0005]
    return {
        "jawOpen": lo_c * jaw,
        "jawForward": lo_c * [0, 0, 0.008],
        "jawLeft": lo_c * [0.008, 0, 0],
        "jawRight": lo_c * [-0.008, 0, 0],
        "mouthClose": -0.9 * lo_c * jaw + up_c * [0, -0.0015, 0],
        "mouthFunnel": 0.25 * narrow + up_c * [0, 0.006, 0.006] + lo_c * [0, -0.007, 0.006],
        "mouthPucker": 0.45 * narrow + np.stack([zero, -0.3 * (p[:, 1] - MOUTH_Y), np.full(len(p), 0.010)], 1),
        "mouthLeft": np.tile([0.008, 0, -0.001], (len(p), 1)),
        "mouthRight": np.tile([-0.008, 0, -0.001], (len(p), 1)),
        "mouthSmileLeft": left * [0.005, 0.007, -0.003],
        "mouthSmileRight": right * [-0.005, 0.007, -0.003],
        "mouthFrownLeft": left * [0.001, -0.006, 0],
        "mouthFrownRight": right * [-0.001, -0.006, 0],
        "mouthDimpleLeft": left * [0.002, 0.0005, -0.004],
        "mouthDimpleRight": right * [-0.002, 0.0005, -0.004],
        "mouthStretchLeft": left * [0.007, -0.001, -0.002],
        "mouthStretchRight": right * [-0.007, -0.001, -0.002],
        "mouthRollLower": lo_c * [0, 0.0025, -0.0045],
        "mouthRollUpper": up_c * [0, -0.0025, -0.0045],
        "mouthShrugLower": lo_c * [0, 0.003, 0.002],
        "mouthShrugUpper": up_c * [0, 0.0025, 0.0015],
        "mouthPressLeft": half_l * press,
        "mouthPressRight": half_r * press,
        "mouthLowerDownLeft": lo_c * smoothstep(-0.5, 0.6, xn)[:, None] * [0, -0.006, 0],
        "mouthLowerDownRight": lo_c * smoothstep(0.5, -0.6, xn)[:, None] * [0, -0.006, 0],
        "mouthUpperUpLeft": up_c * smoothstep(-0.5, 0.6, xn)[:, None] * [0, 0.005, 0],
        "mouthUpperUpRight": up_c * smoothstep(0.5, -0.6, xn)[:, None] * [0, 0.005, 0],
    }
