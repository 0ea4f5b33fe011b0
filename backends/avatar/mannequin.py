"""The built-in avatar: a clothed mannequin built in code on the canonical skeleton's rest pose.

The body is lofted tubes with skin weights of at most four canonical joints per vertex: a shirt
with a crew neck and long sleeves, trousers, shoes, a neck, and hands whose palm, thumb and
fingers are one piece with the wrist. Each arm is one continuous surface from the shoulder to the
hand, and the part of the wrist inside the cuff moves with the forearm, so skin never shows through
the sleeve whatever the pose. The head and face (``mannequin_face``) carry the 52 ARKit morph
targets. Everything is in the skeleton's frame: metres, Y up, facing +Z, the character's left at +X.
"""

from __future__ import annotations

import functools

import numpy as np

from convodrive.backends.avatar.mannequin_face import face_landmarks, face_parts
from convodrive.backends.avatar.mannequin_head import COLORS
from convodrive.backends.avatar.mesh_build import (
    Part,
    chain_weights,
    ellipsoid,
    loft,
    part,
    ramp_weights,
    rigid_weights,
    smoothstep,
    torus,
)
from convodrive.backends.avatar.rig import Material, Rig, Skeleton, Surface, sparse_weights
from convodrive.backends.avatar.skinning import smooth_normals
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS, PARENTS, REST_OFFSETS, REST_POSITIONS

J = JOINT_INDEX
MAX_INFLUENCES = 4

MATERIALS: tuple[Material, ...] = (
    Material("skin", roughness=0.5, scatter=1.0),
    Material("lips", roughness=0.35, scatter=0.8),
    Material("cloth", roughness=0.9),
    Material("shoes", roughness=0.45),
    Material("eyes", roughness=0.08),
    Material("hair", roughness=0.7),
    Material("teeth", roughness=0.3, scatter=0.3),
    Material("mouth", roughness=0.8, scatter=0.5),
)
"""The mannequin's materials, in drawing order; colours live in the vertices."""
MATERIAL_INDEX = {m.name: i for i, m in enumerate(MATERIALS)}

BODY_COLORS: dict[str, tuple[float, float, float]] = {
    "shirt": (0.16, 0.30, 0.44),
    "collar": (0.13, 0.25, 0.37),
    "trousers": (0.15, 0.15, 0.18),
    "shoes": (0.10, 0.075, 0.06),
    "sole": (0.30, 0.28, 0.26),
}


def _out(side: str) -> np.ndarray:
    return np.array([1.0 if side == "left" else -1.0, 0.0, 0.0])


# ---------------------------------------------------------------------------------------- torso

# Torso rings from the shirt's hem to its neckline: height, depth centre, half width, half depth.
_TORSO = np.array(
    [
        [0.93, 0.000, 0.158, 0.100],
        [0.99, 0.000, 0.156, 0.097],
        [1.06, -0.008, 0.142, 0.090],
        [1.15, -0.006, 0.148, 0.096],
        [1.24, 0.000, 0.160, 0.103],
        [1.32, -0.004, 0.171, 0.101],
        [1.37, -0.012, 0.176, 0.092],
        [1.41, -0.017, 0.166, 0.083],
        [1.447, -0.020, 0.134, 0.076],
        [1.475, -0.022, 0.095, 0.070],
        [1.494, -0.022, 0.077, 0.067],
        [1.500, -0.022, 0.071, 0.065],
    ]
)
NECKLINE = _TORSO[-1]


def _torso() -> list[Part]:
    ref = np.array([0.0, 0.0, 1.0])
    keys = np.stack([np.zeros(len(_TORSO)), _TORSO[:, 0], _TORSO[:, 1]], 1)
    v, f, _ = loft(keys, _TORSO[:, 2], _TORSO[:, 3], ref, 28, sub=3, caps=(False, False), power=2.7)
    y = v[:, 1]
    w = ramp_weights(
        y,
        [J["pelvis"], J["spine1"], J["spine2"], J["spine3"]],
        [1.02, 1.12, 1.22],
        [0.04, 0.05, 0.04],
        NUM_JOINTS,
    )
    for side in ("left", "right"):  # the shoulder tops ride the collar bones
        sgn = _out(side)[0]
        c = 0.65 * smoothstep(0.07, 0.16, sgn * v[:, 0]) * smoothstep(1.30, 1.40, y)
        w *= (1 - c)[:, None]
        w[:, J[f"{side}_collar"]] += c
    parts = [part("cloth", v, f, w, BODY_COLORS["shirt"])]
    # a ribbed crew neck over the neckline's edge
    v, f, _ = torus(np.array([0.0, NECKLINE[0], NECKLINE[1]]), (NECKLINE[2], NECKLINE[3]), 0.0075, 8, 32)
    parts.append(part("cloth", v, f, rigid_weights(len(v), J["spine3"], NUM_JOINTS), BODY_COLORS["collar"]))
    # trousers: crotch to under the shirt's hem
    keys = np.array([[0, 0.84, 0.0], [0, 0.90, 0.0], [0, 0.98, 0.0]])
    v, f, _ = loft(
        keys,
        [0.150, 0.158, 0.152],
        [0.095, 0.099, 0.094],
        ref,
        28,
        sub=3,
        caps=(True, False),
        power=2.7,
        cap_length=0.3,
    )
    parts.append(part("cloth", v, f, rigid_weights(len(v), J["pelvis"], NUM_JOINTS), BODY_COLORS["trousers"]))
    return parts


def _neck() -> Part:
    keys = np.array([[0, 1.42, -0.028], [0, 1.48, -0.024], [0, 1.53, -0.014], [0, 1.59, -0.006]])
    v, f, _ = loft(
        keys,
        [0.062, 0.060, 0.057, 0.054],
        [0.058, 0.056, 0.054, 0.054],
        np.array([0, 0, 1.0]),
        20,
        sub=4,
        caps=(False, False),
    )
    w = ramp_weights(v[:, 1], [J["spine3"], J["neck"], J["head"]], [1.455, 1.535], [0.03, 0.03], NUM_JOINTS)
    return part("skin", v, f, w, COLORS["skin"])


# ---------------------------------------------------------------------------------------- arms


def _arm(side: str) -> list[Part]:
    """Sleeve, hand and shoulder cap of one arm."""
    P = REST_POSITIONS
    out = _out(side)
    collar, shoulder, elbow, wrist = (J[f"{side}_{n}"] for n in ("collar", "shoulder", "elbow", "wrist"))
    sx, ex, wx = (out @ P[j] for j in (shoulder, elbow, wrist))
    ref = np.array([0.0, 1.0, 0.0])
    # along the arm (distance from the body's midline), radii across (z) and up (y); the sleeve
    # ends in a rolled cuff that closes onto the wrist a little before the joint
    along = np.array([sx - 0.07, sx, 0.31, ex, 0.57, wx - 0.045, wx - 0.035, wx - 0.027, wx - 0.023])
    across = np.array([0.054, 0.053, 0.047, 0.042, 0.039, 0.0345, 0.0365, 0.0335, 0.0225])
    up = np.array([0.057, 0.055, 0.046, 0.041, 0.036, 0.0305, 0.0325, 0.029, 0.0172])
    line = P[shoulder] + (along - sx)[:, None] * out
    line[:, 1] += np.interp(along, [sx - 0.07, sx, wx], [-0.01, 0.0, 0.0])
    line[:, 2] = np.interp(along, [sx, ex, wx], [P[shoulder][2], P[elbow][2], P[wrist][2] + 0.002])
    v, f, _ = loft(line, across, up, ref, 18, sub=4, caps=(False, False))
    s = v @ out
    w = ramp_weights(s, [collar, shoulder, elbow], [sx - 0.02, ex], [0.035, 0.045], NUM_JOINTS)
    colors = np.where((s > wx - 0.041)[:, None], BODY_COLORS["collar"], BODY_COLORS["shirt"])
    parts = [part("cloth", v, f, w, colors)]
    v, f = ellipsoid(P[shoulder] - 0.014 * out + [0, 0.004, 0.002], np.array([0.054, 0.053, 0.055]), 10, 16)
    parts.append(part("cloth", v, f, rigid_weights(len(v), collar, NUM_JOINTS), BODY_COLORS["shirt"]))
    parts += _hand(side)
    return parts


def _hand(side: str) -> list[Part]:
    """Wrist, palm, thumb and fingers; the wrist starts inside the cuff, bound to the forearm."""
    P = REST_POSITIONS
    out = _out(side)
    sgn = out[0]
    elbow, wrist = J[f"{side}_elbow"], J[f"{side}_wrist"]
    w0 = P[wrist]
    wx = sgn * w0[0]
    ref = np.array([0.0, 1.0, 0.0])
    # along the hand: inside the cuff, the wrist joint, mid palm, the knuckles, the palm's far edge
    along = np.array([wx - 0.05, wx - 0.03, wx - 0.012, wx + 0.004, wx + 0.042, wx + 0.082, wx + 0.094])
    keys = np.stack(
        [
            sgn * along,
            np.array([0.0, 0.0, 0.0, -0.001, -0.003, -0.004, -0.004]) + w0[1],
            np.array([0.002, 0.002, 0.002, 0.0, -0.004, -0.006, -0.006]) + w0[2],
        ],
        1,
    )
    across = [0.0235, 0.024, 0.0245, 0.028, 0.040, 0.042, 0.030]
    thick = [0.0195, 0.019, 0.0185, 0.017, 0.0165, 0.0125, 0.008]
    v, f, _ = loft(keys, across, thick, ref, 18, sub=3, caps=(False, True), power=2.3, cap_length=0.6)
    s = v @ out
    w = ramp_weights(s, [elbow, wrist], [wx - 0.004], [0.016], NUM_JOINTS)
    skin = np.array(COLORS["skin"])
    parts = [part("skin", v, f, w, skin)]
    radii = {"index": 0.0093, "middle": 0.0097, "ring": 0.0091, "pinky": 0.0079}
    for finger, r in radii.items():
        j1, j2, j3 = (J[f"{side}_{finger}{i}"] for i in (1, 2, 3))
        a, b, c = P[j1], P[j2], P[j3]
        tip = c + 0.62 * (c - b)
        keys = np.array([a - 0.45 * (b - a), a, b, c, tip])
        keys[0, 1] -= 0.002
        scale = np.array([1.15, 1.05, 0.95, 0.88, 0.8]) * r
        v, f, rho = loft(keys, scale, scale * 0.86, ref, 10, sub=3, cap_length=0.9)
        w = chain_weights(rho, [wrist, j1, j2, j3], NUM_JOINTS, blend=0.28)
        parts.append(part("skin", v, f, w, _nail_colors(v, tip, c - b, skin)))
    # thumb: from a fleshy base on the palm by the wrist (the thenar pad) out through its joints
    j1, j2, j3 = (J[f"{side}_thumb{i}"] for i in (1, 2, 3))
    a, b, c = P[j1], P[j2], P[j3]
    base = w0 + np.array([0.006 * sgn, -0.004, 0.006])
    keys = np.array([base, 0.5 * (base + a), a, b, c, c + 0.65 * (c - b)])
    radii_t = np.array([0.017, 0.0155, 0.0128, 0.0112, 0.0102, 0.0088])
    v, f, rho = loft(keys, radii_t, radii_t * 0.9, np.array([0.0, 1.0, 0.0]), 12, sub=3, cap_length=0.9)
    w = chain_weights(rho, [wrist, wrist, j1, j2, j3], NUM_JOINTS, blend=0.3)
    parts.append(part("skin", v, f, w, _nail_colors(v, c + 0.65 * (c - b), c - b, skin)))
    return parts


def _nail_colors(v: np.ndarray, tip: np.ndarray, direction: np.ndarray, skin: np.ndarray) -> np.ndarray:
    """Skin with a paler nail on the back of the last phalanx."""
    d = direction / np.linalg.norm(direction)
    back = (v[:, 1] - tip[1]) > 0.002
    near = (v - tip) @ d > -0.014
    nail = (back & near)[:, None]
    return np.where(nail, skin * np.array([1.08, 0.95, 0.95]) + 0.04, skin)


# ---------------------------------------------------------------------------------------- legs


def _leg(side: str) -> list[Part]:
    P = REST_POSITIONS
    ref = np.array([0.0, 0.0, 1.0])
    hip, knee, ankle, foot = (J[f"{side}_{n}"] for n in ("hip", "knee", "ankle", "foot"))
    keys = np.array([P[hip] + [0, 0.06, 0], P[hip], P[knee], P[ankle] + [0, 0.03, 0]])
    v, f, rho = loft(
        keys, [0.085, 0.08, 0.056, 0.046], [0.086, 0.081, 0.057, 0.049], ref, 18, sub=3, caps=(False, False)
    )
    parts = [part("cloth", v, f, chain_weights(rho, [J["pelvis"], hip, knee], NUM_JOINTS), BODY_COLORS["trousers"])]
    x = P[ankle][0]
    keys = np.array([[x, 0.06, -0.075], [x, 0.075, -0.03], [P[foot][0], 0.05, 0.10], [P[foot][0], 0.04, 0.17]])
    v, f, rho = loft(
        keys, [0.040, 0.047, 0.049, 0.036], [0.045, 0.055, 0.034, 0.024], np.array([0.0, 1.0, 0.0]), 16, sub=3
    )
    v[:, 1] = np.maximum(v[:, 1], 0.0)  # a flat sole on the floor
    colors = np.where((v[:, 1] < 0.012)[:, None], BODY_COLORS["sole"], BODY_COLORS["shoes"])
    parts.append(part("shoes", v, f, chain_weights(rho, [ankle, ankle, foot], NUM_JOINTS), colors))
    return parts


# ---------------------------------------------------------------------------------------- assembly


def canonical_skeleton() -> Skeleton:
    """The canonical skeleton as a rig skeleton: no rest rotations, bound where it stands."""
    inverse_bind = np.tile(np.eye(4), (NUM_JOINTS, 1, 1))
    inverse_bind[:, :3, 3] = -REST_POSITIONS
    return Skeleton(
        names=JOINT_NAMES,
        parents=np.array(PARENTS),
        translation=np.array(REST_OFFSETS, float),
        rotation=np.tile(np.eye(3), (NUM_JOINTS, 1, 1)),
        scale=np.ones((NUM_JOINTS, 3)),
        inverse_bind=inverse_bind,
        canonical=np.arange(NUM_JOINTS),
    )


def assemble(parts: list[Part], name: str) -> Rig:
    """Group parts by material into one vertex array per surface, and gather their morph targets."""
    order = sorted(range(len(parts)), key=lambda i: MATERIAL_INDEX[parts[i].material])
    parts = [parts[i] for i in order]
    verts, colors, weights, surfaces = [], [], [], []
    deltas: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    offset = 0
    for material in MATERIALS:
        group = [p for p in parts if p.material == material.name]
        if not group:
            continue
        start = offset
        faces = []
        for p in group:
            verts.append(p.verts)
            colors.append(p.colors)
            weights.append(p.weights)
            faces.append(p.faces + offset - start)
            for key, delta in p.deltas.items():
                deltas.setdefault(key, []).append((np.arange(len(p.verts)) + offset, np.asarray(delta, float)))
            offset += len(p.verts)
        surfaces.append(Surface(MATERIAL_INDEX[material.name], start, offset, np.concatenate(faces).astype(np.uint32)))
    rest = np.concatenate(verts)
    names = tuple(n for n in ARKIT_NAMES if n in deltas)
    index = np.unique(np.concatenate([idx for rows in deltas.values() for idx, _ in rows]))
    position = np.full(len(rest), -1)
    position[index] = np.arange(len(index))
    morph = np.zeros((len(names), len(index), 3))
    for b, key in enumerate(names):
        for idx, delta in deltas[key]:
            np.add.at(morph[b], position[idx], delta)
    all_faces = np.concatenate([s.faces.astype(np.int64) + s.start for s in surfaces])
    normals = smooth_normals(rest, all_faces)
    return Rig(
        name=name,
        rest=rest.astype(np.float32),
        normals=normals.astype(np.float32),
        colors=np.concatenate([np.concatenate(colors), np.ones((len(rest), 1))], 1).astype(np.float32),
        uv=None,
        surfaces=surfaces,
        materials=list(MATERIALS),
        skeleton=canonical_skeleton(),
        weights=sparse_weights(np.concatenate(weights), MAX_INFLUENCES),
        morph_names=names,
        morph_index=index,
        morph_deltas=morph.astype(np.float32),
        landmarks=face_landmarks(),
    )


@functools.lru_cache(maxsize=1)
def build_mannequin() -> Rig:
    """Build (once per process) the mannequin on the canonical rest pose."""
    parts = _torso() + [_neck()]
    for side in ("left", "right"):
        parts += _arm(side) + _leg(side)
    parts += face_parts()
    return assemble(parts, "convodrive mannequin")
