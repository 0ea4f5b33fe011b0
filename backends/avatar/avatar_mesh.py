"""The avatar: a skinned mannequin built procedurally on the canonical skeleton's rest pose.

A lean body (tubes for torso, limbs and fingers) carries skin weights (at most four bones per
vertex); the head carries the face: ARKit-named blendshapes on the mouth, lips, jaw, cheeks and
brows, eyeballs bound to the eye joints for gaze, and eyelids that close along the eyeball's
sphere (a rotation, so a blink never cuts into the eye the way a linear blendshape would).
Everything is in the skeleton's frame: metres, Y up, facing +Z, the character's left at +X.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import scipy.sparse as sp

from convodrive.backends.avatar.mesh_build import (
    chain_weights,
    ellipsoid,
    grid_faces,
    loft,
    normalize,
    orient_outward,
    rigid_weights,
    smoothstep,
)
from convodrive.motion.skeleton import JOINT_INDEX, NUM_JOINTS, REST_POSITIONS

J = JOINT_INDEX
MAX_INFLUENCES = 4

# Materials: roughness of each; colours live in the vertices, so one material serves many parts.
MATERIALS: dict[str, float] = {
    "skin": 0.55,
    "lips": 0.38,
    "cloth": 0.85,
    "eyes": 0.12,
    "hair": 0.9,
    "teeth": 0.3,
    "mouth": 1.0,
}
COLORS: dict[str, tuple[float, float, float]] = {
    "skin": (0.86, 0.64, 0.52),
    "lips": (0.70, 0.36, 0.35),
    "shirt": (0.20, 0.38, 0.52),
    "trousers": (0.17, 0.17, 0.21),
    "shoes": (0.11, 0.09, 0.08),
    "hair": (0.17, 0.11, 0.08),
    "sclera": (0.95, 0.94, 0.92),
    "iris": (0.24, 0.43, 0.52),
    "pupil": (0.02, 0.02, 0.02),
    "teeth": (0.94, 0.92, 0.86),
    "mouth": (0.30, 0.07, 0.08),
    "lash": (0.10, 0.07, 0.06),
}

SHAPES: tuple[str, ...] = (
    "jawOpen",
    "jawForward",
    "jawLeft",
    "jawRight",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "noseSneerLeft",
    "noseSneerRight",
)
"""Face channels with vertex blendshapes; blinks, squints and gaze move the lids and eyes instead."""

# Head geometry (rest pose).
HEAD_CENTER = np.array([0.0, 1.645, 0.005])
HEAD_RADII = np.array([0.077, 0.115, 0.098])
EYE_RADIUS = 0.0115
EYES = (REST_POSITIONS[J["left_eye_smplhf"]].copy(), REST_POSITIONS[J["right_eye_smplhf"]].copy())
MOUTH_Y = 1.572
MOUTH_HALF_WIDTH = 0.025
JAW_PIVOT = np.array([0.0, 1.60, -0.02])
JAW_OPEN_ANGLE = 0.27
"""Radians the mesh's lower face turns about ``JAW_PIVOT`` at ``jawOpen`` = 1 (a mannequin's jaw,
shorter than a skull's). The ``jaw`` joint's rotation is read as the same opening (see
``AvatarPoser.face_weights``), so joint and channel never open the mouth twice."""


def _taper(dy: np.ndarray) -> np.ndarray:
    """Narrower toward the jaw: the head's half-width scale at normalised height ``dy``."""
    return 1.0 - 0.2 * np.maximum(-dy, 0.0) ** 1.5


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


@dataclasses.dataclass
class Lids:
    """Eyelid vertices, placed each frame on spheres around the eyes at an edge angle."""

    index: np.ndarray  # (L,) vertex indices into the avatar
    psi: np.ndarray  # (L,) azimuth around the eye (radians, 0 = straight ahead)
    start: np.ndarray  # (L,) elevation of the lid's fixed edge (radians)
    t: np.ndarray  # (L,) 0 at the fixed edge, 1 at the moving edge
    radius: np.ndarray  # (L,)
    eye: np.ndarray  # (L,) 0 = left eye, 1 = right eye
    upper: np.ndarray  # (L,) bool


@dataclasses.dataclass
class Avatar:
    """Rest geometry, skin weights and face rig, with vertices grouped by material."""

    rest: np.ndarray  # (V, 3) float32
    colors: np.ndarray  # (V, 4) float32 RGBA
    faces: np.ndarray  # (F, 3) int32, global vertex indices
    weights: sp.csr_matrix  # (V, 55)
    material_ranges: dict[str, tuple[int, int]]  # material -> vertex range [start, end)
    material_faces: dict[str, np.ndarray]  # material -> faces indexed within its range
    shape_index: np.ndarray  # (S,) vertices any blendshape moves
    shape_deltas: np.ndarray  # (B, S, 3) in SHAPES order
    lids: Lids
    landmarks: dict[str, np.ndarray]  # rest positions of mouth, eyes, ... (all on the head joint)

    @property
    def num_vertices(self) -> int:
        return len(self.rest)


@dataclasses.dataclass
class _Part:
    material: str
    verts: np.ndarray
    faces: np.ndarray
    weights: np.ndarray  # (N, 55)
    colors: np.ndarray  # (N, 3)
    deltas: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    lid: dict[str, np.ndarray] | None = None


def _part(material: str, verts: np.ndarray, faces: np.ndarray, weights: np.ndarray, color: str | np.ndarray) -> _Part:
    colors = np.broadcast_to(np.asarray(COLORS[color] if isinstance(color, str) else color, float), verts.shape).copy()
    return _Part(material, np.asarray(verts, float), faces, weights, colors)


# ---------------------------------------------------------------------------------------- body


def _torso() -> list[_Part]:
    ref = np.array([0.0, 0.0, 1.0])
    sp3, s1, s2, pel = J["spine3"], J["spine1"], J["spine2"], J["pelvis"]
    ys = np.array([0.84, 0.95, 1.06, 1.19, 1.25, 1.36, 1.45])
    zs = np.array([0.0, 0.0, -0.01, -0.005, 0.0, -0.015, -0.02])
    width = np.array([0.150, 0.165, 0.142, 0.150, 0.165, 0.182, 0.14])
    depth = np.array([0.095, 0.105, 0.092, 0.098, 0.105, 0.098, 0.075])
    keys = np.stack([np.zeros_like(ys), ys, zs], 1)
    parts = []
    # trousers: crotch to the waist; shirt: waist to the shoulders, a little wider where they overlap
    hips = keys[:3].copy()
    hips[2, 1] = 1.0  # the trousers stop under the shirt's hem, where only the pelvis moves them
    v, f, rho = loft(hips, width[:3], depth[:3], ref, 22, sub=3, caps=(True, False), power=2.6, cap_length=0.3)
    parts.append(_part("cloth", v, f, chain_weights(rho, [pel, pel], NUM_JOINTS), "trousers"))
    v, f, rho = loft(keys[1:], width[1:] * 1.05, depth[1:] * 1.07, ref, 22, sub=3, caps=(False, True), power=2.6)
    w = chain_weights(rho + 1, [pel, s1, s2, sp3, sp3], NUM_JOINTS)
    for side in (1, -1):  # shoulder tops follow the collar bones a little
        collar = J["left_collar" if side > 0 else "right_collar"]
        c = 0.6 * smoothstep(0.08, 0.17, side * v[:, 0]) * smoothstep(1.30, 1.39, v[:, 1])
        w *= (1 - c)[:, None]
        w[:, collar] += c
    parts.append(_part("cloth", v, f, w, "shirt"))
    neck = np.array([[0, 1.40, -0.02], [0, 1.48, -0.015], [0, 1.56, 0.0], [0, 1.60, 0.0]])
    v, f, rho = loft(
        neck, [0.05, 0.047, 0.046, 0.046], [0.05, 0.047, 0.046, 0.046], ref, 16, sub=3, caps=(False, False)
    )
    parts.append(_part("skin", v, f, chain_weights(rho, [sp3, J["neck"], J["head"]], NUM_JOINTS), "skin"))
    return parts


def _arm(side: str) -> list[_Part]:
    P = REST_POSITIONS
    sgn = 1.0 if side == "left" else -1.0
    ref = np.array([0.0, 1.0, 0.0])
    collar, shoulder, elbow, wrist = (J[f"{side}_{n}"] for n in ("collar", "shoulder", "elbow", "wrist"))
    out = np.array([sgn, 0.0, 0.0])
    parts = []
    keys = np.array([P[shoulder] - 0.05 * out, P[shoulder], P[elbow], P[elbow] + 0.07 * out])
    v, f, rho = loft(keys, [0.05, 0.048, 0.040, 0.038], [0.053, 0.05, 0.041, 0.039], ref, 14, sub=3)
    parts.append(_part("cloth", v, f, chain_weights(rho, [collar, shoulder, elbow], NUM_JOINTS), "shirt"))
    v, f = ellipsoid(P[shoulder] - 0.012 * out + [0, 0.002, 0], np.array([0.05, 0.05, 0.048]), 10, 14)
    parts.append(_part("cloth", v, f, rigid_weights(len(v), collar, NUM_JOINTS), "shirt"))
    keys = np.array([P[elbow] - 0.03 * out, P[elbow], P[wrist]])
    v, f, rho = loft(keys, [0.036, 0.035, 0.025], [0.037, 0.036, 0.022], ref, 12, sub=4)
    parts.append(_part("skin", v, f, chain_weights(rho, [shoulder, elbow], NUM_JOINTS), "skin"))
    parts += _hand(side)
    return parts


def _hand(side: str) -> list[_Part]:
    P = REST_POSITIONS
    sgn = 1.0 if side == "left" else -1.0
    ref = np.array([0.0, 1.0, 0.0])
    wrist, elbow = J[f"{side}_wrist"], J[f"{side}_elbow"]
    w0 = P[wrist]
    palm = np.array(
        [w0 + [-0.012 * sgn, 0, -0.012], w0 + [0.03 * sgn, -0.002, -0.024], w0 + [0.083 * sgn, -0.002, -0.026]]
    )
    v, f, rho = loft(palm, [0.026, 0.041, 0.043], [0.017, 0.015, 0.012], ref, 12, sub=2)
    parts = [_part("skin", v, f, chain_weights(rho, [wrist, wrist], NUM_JOINTS, before=elbow), "skin")]
    radii = {"index": 0.0085, "middle": 0.0088, "ring": 0.0082, "pinky": 0.0072, "thumb": 0.0100}
    for finger, r in radii.items():
        j1, j2, j3 = (J[f"{side}_{finger}{i}"] for i in (1, 2, 3))
        a, b, c = P[j1], P[j2], P[j3]
        if finger == "thumb":  # the thumb's metacarpal starts inside the palm, by the wrist
            keys = np.array([w0 + [0.018 * sgn, -0.006, -0.008], a, b, c, c + 0.55 * (c - b)])
        else:
            keys = np.array([a - 0.3 * (b - a), a, b, c, c + 0.8 * (c - b)])
        scale = np.array([1.1, 1.0, 0.93, 0.86, 0.78]) * r
        v, f, rho = loft(keys, scale, scale * 0.88, ref, 7, sub=2)
        parts.append(_part("skin", v, f, chain_weights(rho, [wrist, j1, j2, j3], NUM_JOINTS, blend=0.25), "skin"))
    return parts


def _leg(side: str) -> list[_Part]:
    P = REST_POSITIONS
    ref = np.array([0.0, 0.0, 1.0])
    hip, knee, ankle, foot = (J[f"{side}_{n}"] for n in ("hip", "knee", "ankle", "foot"))
    keys = np.array([P[hip] + [0, 0.06, 0], P[hip], P[knee], P[ankle] + [0, 0.02, 0]])
    v, f, rho = loft(keys, [0.085, 0.08, 0.055, 0.045], [0.085, 0.08, 0.056, 0.048], ref, 14, sub=3)
    parts = [_part("cloth", v, f, chain_weights(rho, [J["pelvis"], hip, knee], NUM_JOINTS), "trousers")]
    x = P[ankle][0]
    keys = np.array([[x, 0.055, -0.085], [x, 0.07, -0.03], [P[foot][0], 0.045, 0.10], [P[foot][0], 0.038, 0.165]])
    v, f, rho = loft(
        keys, [0.038, 0.045, 0.048, 0.034], [0.04, 0.05, 0.03, 0.022], np.array([0.0, 1.0, 0.0]), 12, sub=3
    )
    parts.append(_part("cloth", v, f, chain_weights(rho, [ankle, ankle, foot], NUM_JOINTS), "shoes"))
    return parts


# ---------------------------------------------------------------------------------------- head


def _head() -> _Part:
    rows, cols = 40, 48
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
    part = _part("skin", verts, faces, rigid_weights(len(verts), J["head"], NUM_JOINTS), "skin")
    part.deltas = _skin_deltas(verts)
    return part


def _skin_deltas(p: np.ndarray) -> dict[str, np.ndarray]:
    """Blendshapes of the face skin: the lower face rides the jaw; cheeks and corners follow the lips."""
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
    out["mouthLeft"] = near_mouth[:, None] * [0.006, 0, 0]
    out["mouthRight"] = near_mouth[:, None] * [-0.006, 0, 0]
    out["mouthPucker"] = near_mouth[:, None] * np.stack([-0.3 * p[:, 0], np.zeros(len(p)), np.full(len(p), 0.004)], 1)
    for side, sgn in (("Left", 1.0), ("Right", -1.0)):
        corner = np.exp(-(((p[:, 0] - sgn * 0.028) / 0.013) ** 2 + ((p[:, 1] - MOUTH_Y - 0.002) / 0.012) ** 2)) * window
        out[f"mouthSmile{side}"] = corner[:, None] * [sgn * 0.004, 0.006, -0.002]
        out[f"mouthFrown{side}"] = corner[:, None] * [0, -0.005, 0]
        out[f"mouthStretch{side}"] = corner[:, None] * [sgn * 0.005, -0.001, -0.001]
        cheek = np.exp(-(((p[:, 0] - sgn * 0.045) / 0.02) ** 2 + ((p[:, 1] - MOUTH_Y - 0.012) / 0.02) ** 2)) * front
        out["cheekPuff"] = out.get("cheekPuff", 0) + cheek[:, None] * [sgn * 0.008, 0, 0.004]
        nose = np.exp(-(((p[:, 0] - sgn * 0.012) / 0.012) ** 2 + ((p[:, 1] - 1.605) / 0.012) ** 2)) * front
        out[f"noseSneer{side}"] = nose[:, None] * [0, 0.003, 0.001]
    return out


def _mouth_rig_deltas(p: np.ndarray, up: np.ndarray, lo: np.ndarray, xn: np.ndarray) -> dict[str, np.ndarray]:
    """Blendshapes shared by the lips and the mouth's inside.

    ``up``/``lo`` say how much a vertex belongs to the upper or lower lip, ``xn`` is x across the
    mouth normalised to [-1, 1]; lips and the inside then open, round and smile together.
    """
    zero = np.zeros(len(p))
    lo_c, up_c = lo[:, None], up[:, None]
    jaw = jaw_delta(p)
    left, right = smoothstep(0.3, 0.95, xn)[:, None], smoothstep(-0.3, -0.95, xn)[:, None]
    narrow = np.stack([-p[:, 0], zero, zero], 1)
    out = {
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
        "mouthStretchLeft": left * [0.007, -0.001, -0.002],
        "mouthStretchRight": right * [-0.007, -0.001, -0.002],
        "mouthLowerDownLeft": lo_c * smoothstep(-0.5, 0.6, xn)[:, None] * [0, -0.006, 0],
        "mouthLowerDownRight": lo_c * smoothstep(0.5, -0.6, xn)[:, None] * [0, -0.006, 0],
        "mouthUpperUpLeft": up_c * smoothstep(-0.5, 0.6, xn)[:, None] * [0, 0.005, 0],
        "mouthUpperUpRight": up_c * smoothstep(0.5, -0.6, xn)[:, None] * [0, 0.005, 0],
    }
    return out


def _lips() -> _Part:
    nu, nv = 36, 8
    uu = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    vv = np.linspace(0, 2 * np.pi, nv, endpoint=False)
    cu, su = np.cos(uu), np.sin(uu)
    a, b = MOUTH_HALF_WIDTH, 0.0038
    cx, cy = a * cu, MOUTH_Y + b * su
    cz = surface_z(cx, cy) + 0.0045
    r = np.where(su > 0, 0.0040, 0.0049) * (0.35 + 0.65 * np.abs(su) ** 0.5)
    radial = normalize(np.stack([cu / a, su / b, np.zeros(nu)], 1))
    fwd = np.array([0.0, 0.0, 1.0])
    ring = np.stack([cx, cy, cz], 1)
    verts = (
        ring[:, None]
        + r[:, None, None] * (np.cos(vv)[None, :, None] * radial[:, None] + 0.9 * np.sin(vv)[None, :, None] * fwd)
    ).reshape(-1, 3)
    faces = orient_outward(verts, _torus_faces(nu, nv), np.repeat(ring, nv, axis=0))
    part = _part("lips", verts, faces, rigid_weights(len(verts), J["head"], NUM_JOINTS), "lips")
    s = np.repeat(su, nv)
    up, lo = np.maximum(s, 0) ** 0.7, np.maximum(-s, 0) ** 0.7
    part.deltas = _mouth_rig_deltas(verts, up, lo, np.repeat(cu, nv))
    return part


def _torus_faces(nu: int, nv: int) -> np.ndarray:
    faces = []
    for i in range(nu):
        for j in range(nv):
            a, b = i * nv + j, i * nv + (j + 1) % nv
            c, d = ((i + 1) % nu) * nv + j, ((i + 1) % nu) * nv + (j + 1) % nv
            faces += [(a, b, d), (a, d, c)]
    return np.array(faces, dtype=np.int64)


def _mouth_inside() -> list[_Part]:
    """A dark lens between the lips that stretches as they part, and two rows of teeth."""
    nx, ns = 16, 5
    xn = np.linspace(-1, 1, nx)
    s = np.linspace(-1, 1, ns)
    x = np.repeat(xn[None] * MOUTH_HALF_WIDTH * 0.98, ns, 0)
    prof = np.repeat(np.maximum(1 - xn**2, 0.05)[None] ** 0.35, ns, 0)
    y = MOUTH_Y + s[:, None] * 0.0008 * prof
    z = surface_z(x, MOUTH_Y) + 0.0012
    verts = np.stack([x, y, z], -1).reshape(-1, 3)
    faces = orient_outward(verts, grid_faces(ns, nx, wrap=False), verts - [0, 0, 0.01])
    inside = _part("mouth", verts, faces, rigid_weights(len(verts), J["head"], NUM_JOINTS), "mouth")
    sv = np.repeat(s, nx)
    inside.deltas = _mouth_rig_deltas(
        verts, (1 + sv) / 2 * prof.ravel(), (1 - sv) / 2 * prof.ravel(), x.ravel() / MOUTH_HALF_WIDTH
    )
    parts = [inside]
    for lower, (y0, y1) in ((False, (MOUTH_Y - 0.004, MOUTH_Y + 0.007)), (True, (MOUTH_Y - 0.003, MOUTH_Y + 0.004))):
        tx = np.linspace(-0.019, 0.019, 12)
        ty = np.array([y0, y1])
        gx, gy = np.meshgrid(tx, ty)
        gz = surface_z(gx, MOUTH_Y) + (0.0022 if lower else 0.0028)
        verts = np.stack([gx, gy, gz], -1).reshape(-1, 3)
        faces = orient_outward(verts, grid_faces(2, 12, wrap=False), verts - [0, 0, 0.01])
        teeth = _part("teeth", verts, faces, rigid_weights(len(verts), J["head"], NUM_JOINTS), "teeth")
        if lower:
            ones = np.ones(len(verts))
            deltas = _mouth_rig_deltas(verts, 0 * ones, ones, verts[:, 0] / MOUTH_HALF_WIDTH)
            teeth.deltas = {k: deltas[k] for k in ("jawOpen", "jawForward", "jawLeft", "jawRight")}
        parts.append(teeth)
    return parts


def _eyes() -> list[_Part]:
    parts = []
    for side, center in zip(("left", "right"), EYES):
        v, f = ellipsoid(center, np.full(3, EYE_RADIUS), 14, 18)
        cos_axis = normalize(v - center)[:, 2]
        colors = np.where(
            (cos_axis > np.cos(0.24))[:, None],
            COLORS["pupil"],
            np.where((cos_axis > np.cos(0.48))[:, None], COLORS["iris"], COLORS["sclera"]),
        )
        parts.append(_part("eyes", v, f, rigid_weights(len(v), J[f"{side}_eye_smplhf"], NUM_JOINTS), colors))
    return parts


LID_UPPER_TOP = np.radians(80.0)
LID_LOWER_BOTTOM = np.radians(-75.0)
LID_REST_EDGES = np.radians([22.0, -30.0, 22.0, -30.0])


def _lids() -> list[_Part]:
    parts = []
    for eye_id, center in enumerate(EYES):
        for upper in (True, False):
            rows, cols = 6, 13
            psi = np.repeat(np.linspace(-1.35, 1.35, cols)[None], rows, 0).ravel()
            t = np.repeat(np.linspace(0, 1, rows)[:, None], cols, 1).ravel()
            radius = EYE_RADIUS * (1.16 if upper else 1.10)
            start = LID_UPPER_TOP if upper else LID_LOWER_BOTTOM
            colors = np.where((t > 0.99)[:, None] & upper, COLORS["lash"], COLORS["skin"])
            verts = lid_positions(
                np.full(len(t), eye_id),
                psi,
                np.full(len(t), start),
                t,
                np.full(len(t), radius),
                LID_REST_EDGES,
                np.full(len(t), upper),
            )
            faces = orient_outward(verts, grid_faces(rows, cols, wrap=False), center)
            part = _part("skin", verts, faces, rigid_weights(len(verts), J["head"], NUM_JOINTS), colors)
            part.lid = {
                "psi": psi,
                "start": np.full(len(t), start),
                "t": t,
                "radius": np.full(len(t), radius),
                "eye": np.full(len(t), eye_id),
                "upper": np.full(len(t), upper),
            }
            parts.append(part)
    return parts


def lid_positions(
    eye: np.ndarray,
    psi: np.ndarray,
    start: np.ndarray,
    t: np.ndarray,
    radius: np.ndarray,
    edges: np.ndarray,
    upper: np.ndarray | None = None,
) -> np.ndarray:
    """Lid vertices on the sphere around their eye; ``edges`` (4,) = edge elevations for
    (left upper, left lower, right upper, right lower), radians."""
    kind = np.zeros(len(t), int) if upper is None else np.where(upper, 0, 1)
    edge = edges[eye.astype(int) * 2 + kind]
    beta = start + t * (edge - start)
    d = np.stack([np.cos(beta) * np.sin(psi), np.sin(beta), np.cos(beta) * np.cos(psi)], 1)
    centers = np.stack(EYES)[eye.astype(int)]
    return centers + d * radius[:, None]


def _features() -> list[_Part]:
    """Nose, ears, hair cap and brows."""
    head = J["head"]
    parts = []
    ny = 1.603
    v, f = ellipsoid(np.array([0.0, ny, float(surface_z(0.0, ny)) - 0.002]), np.array([0.011, 0.022, 0.017]), 10, 14)
    v[:, 2] += 0.006 * smoothstep(ny + 0.02, ny - 0.015, v[:, 1]) * (v[:, 2] > surface_z(0.0, ny))  # tip forward
    nose = _part("skin", v, f, rigid_weights(len(v), head, NUM_JOINTS), "skin")
    nose.deltas = {f"noseSneer{s}": np.tile([0, 0.002, 0], (len(v), 1)) for s in ("Left", "Right")}
    parts.append(nose)
    for sgn in (1, -1):
        v, f = ellipsoid(np.array([sgn * 0.074, 1.632, -0.004]), np.array([0.008, 0.026, 0.016]), 8, 12)
        parts.append(_part("skin", v, f, rigid_weights(len(v), head, NUM_JOINTS), "skin"))
    # hair: a shell over the head, hairline high at the front, low at the back
    rows, cols = 12, 48
    lon = np.linspace(-np.pi, np.pi, cols, endpoint=False)
    edge = 0.06 + 0.48 * np.cos(lon)
    edge = np.where(np.cos(lon) > 0, edge, 0.06 + 0.55 * np.cos(lon))
    k = np.linspace(0, 1, rows)[:, None] ** 0.8
    dy = edge[None] + (0.995 - edge[None]) * k
    c = np.sqrt(1 - dy**2)
    d = np.stack([c * np.sin(lon), dy, c * np.cos(lon)], -1).reshape(-1, 3)
    v = HEAD_CENTER + (head_point(d) - HEAD_CENTER) * 1.06 + [0, 0.004, -0.002]
    f = orient_outward(v, grid_faces(rows, cols, wrap=True), HEAD_CENTER)
    parts.append(_part("hair", v, f, rigid_weights(len(v), head, NUM_JOINTS), "hair"))
    for sgn, side in ((1, "Left"), (-1, "Right")):
        tn = np.linspace(0, 1, 6)
        x = sgn * (0.011 + 0.036 * tn)
        y = EYES[0][1] + 0.021 + 0.004 * np.sin(np.pi * tn * 0.9)
        keys = np.stack([x, y, surface_z(x, y) + 0.0015], 1)
        v, f, rho = loft(keys, np.full(6, 0.0018), 0.0032 - 0.0012 * tn, np.array([0, 1.0, 0]), 6, sub=2)
        brow = _part("hair", v, f, rigid_weights(len(v), head, NUM_JOINTS), "hair")
        t = np.clip((np.abs(v[:, 0]) - 0.011) / 0.036, 0.0, 1.0)
        inner, outer = (1 - t) ** 1.5, t**1.5
        brow.deltas = {
            f"browDown{side}": np.stack([-sgn * 0.002 * (1 - t), np.full(len(v), -0.005), np.zeros(len(v))], 1),
            "browInnerUp": inner[:, None] * [0, 0.007, 0],
            f"browOuterUp{side}": outer[:, None] * [0, 0.007, 0],
        }
        for dlt in brow.deltas.values():  # ride the forehead: keep the brow on the skin
            moved = v + dlt
            dlt[:, 2] += surface_z(moved[:, 0], moved[:, 1]) - surface_z(v[:, 0], v[:, 1])
        parts.append(brow)
    return parts


# ---------------------------------------------------------------------------------------- assembly


def _assemble(parts: list[_Part]) -> Avatar:
    order = sorted(range(len(parts)), key=lambda i: list(MATERIALS).index(parts[i].material))
    parts = [parts[i] for i in order]
    verts, colors, faces, weights = [], [], [], []
    ranges: dict[str, tuple[int, int]] = {}
    mat_faces: dict[str, list[np.ndarray]] = {}
    shape_rows: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {s: [] for s in SHAPES}
    lid_fields: dict[str, list[np.ndarray]] = {}
    lid_index = []
    offset = 0
    for part in parts:
        n = len(part.verts)
        start = ranges.get(part.material, (offset, offset))[0]
        ranges[part.material] = (start, offset + n)
        verts.append(part.verts)
        colors.append(part.colors)
        faces.append(part.faces + offset)
        mat_faces.setdefault(part.material, []).append(part.faces + offset - start)
        weights.append(part.weights)
        for name, delta in part.deltas.items():
            shape_rows[name].append((np.arange(n) + offset, np.asarray(delta, float)))
        if part.lid is not None:
            lid_index.append(np.arange(n) + offset)
            for key, val in part.lid.items():
                lid_fields.setdefault(key, []).append(val)
        offset += n
    rest = np.concatenate(verts)
    index = np.unique(np.concatenate([idx for rows in shape_rows.values() for idx, _ in rows]))
    position = {v: i for i, v in enumerate(index)}
    deltas = np.zeros((len(SHAPES), len(index), 3))
    for b, name in enumerate(SHAPES):
        for idx, delta in shape_rows[name]:
            deltas[b, [position[i] for i in idx]] += delta
    lids = Lids(index=np.concatenate(lid_index), **{k: np.concatenate(v) for k, v in lid_fields.items()})
    landmarks = {
        "mouth": np.array([0.0, MOUTH_Y, float(surface_z(0.0, MOUTH_Y))]),
        "left_eye": EYES[0].copy(),
        "right_eye": EYES[1].copy(),
        "nose": np.array([0.0, 1.603, float(surface_z(0.0, 1.603)) + 0.015]),
        "chin": np.array([0.0, MOUTH_Y - 0.035, float(surface_z(0.0, MOUTH_Y - 0.035))]),
    }
    return Avatar(
        rest=rest.astype(np.float32),
        colors=np.concatenate([np.concatenate(colors), np.ones((len(rest), 1))], 1).astype(np.float32),
        faces=np.concatenate(faces).astype(np.int32),
        weights=_sparse_weights(np.concatenate(weights)),
        material_ranges=ranges,
        material_faces={m: np.concatenate(f).astype(np.uint32) for m, f in mat_faces.items()},
        shape_index=index,
        shape_deltas=deltas.astype(np.float32),
        lids=lids,
        landmarks=landmarks,
    )


def _sparse_weights(dense: np.ndarray) -> sp.csr_matrix:
    """Keep the ``MAX_INFLUENCES`` largest weights per vertex, renormalised to sum to one."""
    keep = np.argsort(-dense, axis=1)[:, :MAX_INFLUENCES]
    rows = np.repeat(np.arange(len(dense)), MAX_INFLUENCES)
    vals = np.take_along_axis(dense, keep, 1)
    vals = vals / vals.sum(1, keepdims=True)
    m = sp.csr_matrix((vals.ravel(), (rows, keep.ravel())), shape=dense.shape)
    m.eliminate_zeros()
    return m


@functools.lru_cache(maxsize=1)
def build_avatar() -> Avatar:
    """Build (once per process) the avatar on the canonical rest pose."""
    parts = _torso()
    for side in ("left", "right"):
        parts += _arm(side) + _leg(side)
    parts += [_head(), _lips()] + _mouth_inside() + _eyes() + _lids() + _features()
    return _assemble(parts)
