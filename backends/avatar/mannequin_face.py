"""The mannequin's face: lips, mouth, eyes, lids, nose, ears, brows and hair, set on the skull of
``mannequin_head``; with the skin's they carry the 52 ARKit morph targets.

Every face channel is a linear morph target, as in any glTF avatar, so the exported mannequin
moves exactly as the built-in one: the jaw's opening is the lower face turned about a pivot, the
lids slide along spheres around the eyes (a blink is the lid's edge turned down, taken as a
straight line, which stays clear of the eyeball because the lid sits a fifth of a radius above
it), and the eyeballs turn with the eye joints. All parts hang from the ``head`` joint.
"""

from __future__ import annotations

import numpy as np

from convodrive.backends.avatar.mannequin_head import (
    COLORS,
    EYE_RADIUS,
    EYES,
    HEAD_CENTER,
    HEAD_RADII,
    MOUTH_HALF_WIDTH,
    MOUTH_Y,
    J,
    gauss,
    head_part,
    head_point,
    head_rigid,
    jaw_delta,
    mouth_rig_deltas,
    skin_colors,
    surface_z,
)
from convodrive.backends.avatar.mesh_build import (
    Part,
    ellipsoid,
    grid_faces,
    loft,
    normalize,
    orient_outward,
    part,
    rigid_weights,
    smoothstep,
)
from convodrive.motion.skeleton import NUM_JOINTS, REST_POSITIONS


def torus_faces(nu: int, nv: int) -> np.ndarray:
    """Faces of an (nu x nv) grid closed in both directions."""
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a, b = i * nv + j, i * nv + (j + 1) % nv
    c, d = ((i + 1) % nu) * nv + j, ((i + 1) % nu) * nv + (j + 1) % nv
    return np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])


def _lips() -> Part:
    nu, nv = 40, 8
    uu = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    vv = np.linspace(0, 2 * np.pi, nv, endpoint=False)
    cu, su = np.cos(uu), np.sin(uu)
    a, b = MOUTH_HALF_WIDTH, 0.0038
    cx, cy = a * cu, MOUTH_Y + b * su
    cz = surface_z(cx, cy) + 0.003
    r = np.where(su > 0, 0.0038, 0.0047) * (0.35 + 0.65 * np.abs(su) ** 0.5)
    radial = normalize(np.stack([cu / a, su / b, np.zeros(nu)], 1))
    fwd = np.array([0.0, 0.0, 1.0])
    ring = np.stack([cx, cy, cz], 1)
    verts = (
        ring[:, None]
        + r[:, None, None] * (np.cos(vv)[None, :, None] * radial[:, None] + 0.75 * np.sin(vv)[None, :, None] * fwd)
    ).reshape(-1, 3)
    faces = orient_outward(verts, torus_faces(nu, nv), np.repeat(ring, nv, axis=0))
    # a little darker where the lips meet, lighter on their fullest part
    inner = np.repeat(np.cos(vv)[None, :] < -0.3, nu, 0).ravel()
    colors = np.where(inner[:, None], np.array(COLORS["lips"]) * 0.8, COLORS["lips"])
    p = head_rigid(part("lips", verts, faces, np.zeros(0), colors))
    s = np.repeat(su, nv)
    up, lo = np.maximum(s, 0) ** 0.7, np.maximum(-s, 0) ** 0.7
    p.deltas = mouth_rig_deltas(verts, up, lo, np.repeat(cu, nv))
    return p


def _mouth_inside() -> list[Part]:
    """A dark lens between the lips that stretches as they part, two rows of teeth and a tongue."""
    nx, ns = 16, 5
    xn = np.linspace(-1, 1, nx)
    s = np.linspace(-1, 1, ns)
    x = np.repeat(xn[None] * MOUTH_HALF_WIDTH * 0.98, ns, 0)
    prof = np.repeat(np.maximum(1 - xn**2, 0.05)[None] ** 0.35, ns, 0)
    y = MOUTH_Y + s[:, None] * 0.0008 * prof
    z = surface_z(x, MOUTH_Y) + 0.0012
    verts = np.stack([x, y, z], -1).reshape(-1, 3)
    faces = orient_outward(verts, grid_faces(ns, nx, wrap=False), verts - [0, 0, 0.01])
    depth = np.repeat((1 - s) / 2, nx)[:, None]  # the floor of the mouth shows the tongue's colour
    colors = np.array(COLORS["mouth"]) + 0.35 * depth * (np.array(COLORS["tongue"]) - COLORS["mouth"])
    inside = head_rigid(part("mouth", verts, faces, np.zeros(0), colors))
    sv = np.repeat(s, nx)
    inside.deltas = mouth_rig_deltas(
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
        teeth = head_rigid(part("teeth", verts, faces, np.zeros(0), COLORS["teeth"]))
        if lower:
            ones = np.ones(len(verts))
            deltas = mouth_rig_deltas(verts, 0 * ones, ones, verts[:, 0] / MOUTH_HALF_WIDTH)
            teeth.deltas = {k: deltas[k] for k in ("jawOpen", "jawForward", "jawLeft", "jawRight")}
        parts.append(teeth)
    # the tongue lies behind the mouth's lens until tongueOut brings it out between the lips
    sz = float(surface_z(0.0, MOUTH_Y))
    v, f = ellipsoid(np.array([0.0, MOUTH_Y - 0.004, sz - 0.022]), np.array([0.016, 0.0045, 0.02]), 8, 14)
    tongue = head_rigid(part("mouth", v, f, np.zeros(0), COLORS["tongue"]))
    tip = smoothstep(sz - 0.03, sz - 0.004, v[:, 2])[:, None]
    tongue.deltas = {
        "jawOpen": jaw_delta(v),
        "tongueOut": tip * [0, -0.004, 0.028] + [0, -0.002, 0.004],
        **{
            k: np.tile(d, (len(v), 1))
            for k, d in (("jawForward", [0, 0, 0.008]), ("jawLeft", [0.008, 0, 0]), ("jawRight", [-0.008, 0, 0]))
        },
    }
    parts.append(tongue)
    return parts


# ---------------------------------------------------------------------------------------- eyes


def _eyeball(center: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sphere whose pole looks forward (+Z), with rings packed where the pupil and the iris end,
    so both edges are round and crisp: vertices, faces, and each vertex's angle off the sight line."""
    angles = np.array([0.08, 0.16, 0.205, 0.225, 0.3, 0.38, 0.45, 0.49, 0.515, 0.6, 0.8, 1.05, 1.35, 1.7, 2.1, 2.6])
    cols = 28
    lon = np.linspace(0, 2 * np.pi, cols, endpoint=False)
    ring = np.stack(
        [
            np.sin(angles)[:, None] * np.cos(lon),
            np.sin(angles)[:, None] * np.sin(lon),
            np.repeat(np.cos(angles)[:, None], cols, 1),
        ],
        -1,
    )
    d = np.concatenate([[[0.0, 0.0, 1.0]], ring.reshape(-1, 3), [[0.0, 0.0, -1.0]]])
    front, back, n = 0, len(d) - 1, len(angles) * cols
    first, last = np.arange(cols) + 1, np.arange(cols) + 1 + n - cols
    faces = np.concatenate(
        [
            np.stack([np.full(cols, front), first, np.roll(first, -1)], 1),
            grid_faces(len(angles), cols, wrap=True) + 1,
            np.stack([last, np.full(cols, back), np.roll(last, -1)], 1),
        ]
    )
    verts = center + EYE_RADIUS * d
    return verts, orient_outward(verts, faces, center), np.concatenate([[0.0], np.repeat(angles, cols), [np.pi]])


def _eyes() -> list[Part]:
    """Eyeballs bound to the eye joints: a shaded sclera, a ringed iris and a pupil."""
    parts = []
    c = {k: np.array(v) for k, v in COLORS.items()}
    for side, center in zip(("left", "right"), EYES):
        v, f, angle = _eyeball(center)
        iris_t = np.clip((angle - 0.22) / 0.28, 0, 1)[:, None]
        iris = c["iris_inner"] + smoothstep(0.0, 0.6, iris_t) * (c["iris"] - c["iris_inner"])
        iris = iris + smoothstep(0.75, 1.0, iris_t) * (c["limbus"] - iris)
        sclera = c["sclera"] + smoothstep(0.9, 1.6, angle)[:, None] * (c["sclera_edge"] - c["sclera"])
        colors = np.where((angle < 0.215)[:, None], c["pupil"], np.where((angle < 0.5)[:, None], iris, sclera))
        parts.append(part("eyes", v, f, rigid_weights(len(v), J[f"{side}_eye_smplhf"], NUM_JOINTS), colors))
    return parts


LID_UPPER_TOP = np.radians(80.0)
LID_LOWER_BOTTOM = np.radians(-75.0)
LID_REST = np.radians([24.0, -27.0])
"""Rest elevation of the upper and the lower lid's edge, radians from the eye's horizon."""
LID_RADIUS = (1.15 * EYE_RADIUS, 1.09 * EYE_RADIUS)

# Each eye channel moves the edges of the upper and lower lid (degrees) and slides both sideways.
_LID_MOVES: dict[str, tuple[float, float, float]] = {
    "eyeBlink": (-47.0, 3.0, 0.0),
    "eyeWide": (12.0, -3.0, 0.0),
    "eyeSquint": (-8.0, 12.0, 0.0),
    "eyeLookDown": (-17.5, -7.5, 0.0),
    "eyeLookUp": (17.5, 7.5, 0.0),
    "eyeLookOut": (0.0, 0.0, 6.0),
    "eyeLookIn": (0.0, 0.0, -6.0),
    "cheekSquint": (0.0, 6.0, 0.0),
}


LID_CORNER = np.radians(-3.0)
"""Elevation where the lids meet at the corners of the eye (the canthi)."""
LID_SPAN = 0.9
"""Azimuth (radians from the line of sight) of the eye's corners."""


def lid_points(
    center: np.ndarray, psi: np.ndarray, start: float, t: np.ndarray, radius: float, edge: float
) -> np.ndarray:
    """Lid vertices on the sphere of ``radius`` around ``center`` at azimuth ``psi``: elevation from
    the fixed ``start`` (t = 0) to the moving edge (t = 1), which lies at ``edge`` over the eye's
    middle and curves to the corners, so the opening is almond-shaped."""
    shape = np.clip(np.cos(np.clip(psi / LID_SPAN, -1, 1) * np.pi / 2), 0, 1) ** 0.6
    moving = LID_CORNER + (edge - LID_CORNER) * shape
    beta = start + t * (moving - start)
    return center + radius * np.stack([np.cos(beta) * np.sin(psi), np.sin(beta), np.cos(beta) * np.cos(psi)], 1)


def _lids() -> list[Part]:
    parts = []
    for (side, sgn), center in zip((("Left", 1.0), ("Right", -1.0)), EYES):
        for k, upper in enumerate((True, False)):
            rows, cols = 7, 21
            psi = np.repeat(np.linspace(-1.85, 1.85, cols)[None], rows, 0).ravel()  # round the eyeball's sides
            t = np.repeat(np.linspace(0, 1, rows)[:, None], cols, 1).ravel()
            start = LID_UPPER_TOP if upper else LID_LOWER_BOTTOM
            radius, rest_edge = LID_RADIUS[k], LID_REST[k]
            verts = lid_points(center, psi, start, t, radius, rest_edge)
            skin = np.array(COLORS["socket"])
            if upper:
                colors = np.where((t > 0.97)[:, None], COLORS["lash"], np.where((t > 0.8)[:, None], skin * 0.92, skin))
            else:
                colors = np.where((t > 0.95)[:, None], np.array(COLORS["blush"]) * 0.95, skin)
            faces = orient_outward(verts, grid_faces(rows, cols, wrap=False), center)
            p = head_rigid(part("skin", verts, faces, np.zeros(0), colors))
            for channel, (d_up, d_lo, d_psi) in _LID_MOVES.items():
                edge = rest_edge + np.radians(d_up if upper else d_lo)
                shifted = psi + sgn * np.radians(d_psi) * t  # the moving edge follows the gaze sideways
                moved = lid_points(center, shifted, start, t, radius, edge)
                if np.abs(moved - verts).max() > 0:
                    p.deltas[f"{channel}{side}"] = moved - verts
            parts.append(p)
    return parts


# ---------------------------------------------------------------------------------------- features


def _nose() -> list[Part]:
    """A bridge narrowing between the eyes, a rounded tip and the wings of the nostrils."""
    ys = np.array([1.628, 1.614, 1.601, 1.592, 1.585])
    zs = surface_z(0.0, ys) + np.array([-0.003, 0.003, 0.008, 0.0115, 0.005])
    keys = np.stack([np.zeros(5), ys, zs], 1)
    v, f, _ = loft(
        keys,
        [0.0060, 0.0068, 0.0082, 0.0105, 0.0085],
        [0.0060, 0.0064, 0.0075, 0.0090, 0.0060],
        np.array([0, 0, 1.0]),
        14,
        sub=3,
        caps=(False, True),
        cap_length=0.8,
    )
    colors = skin_colors(v)
    nose = head_rigid(part("skin", v, f, np.zeros(0), colors))
    parts = [nose]
    for sgn in (1, -1):
        center = np.array([sgn * 0.0105, 1.5875, float(surface_z(sgn * 0.0105, 1.5875)) + 0.002])
        v, f = ellipsoid(center, np.array([0.0052, 0.0048, 0.0064]), 8, 12)
        parts.append(head_rigid(part("skin", v, f, np.zeros(0), skin_colors(v) * 0.97)))
    for p in parts:
        p.deltas = {f"noseSneer{s}": np.tile([0, 0.002, 0.0005], (len(p.verts), 1)) for s in ("Left", "Right")}
    return parts


def _ears() -> list[Part]:
    parts = []
    for sgn in (1, -1):
        center = np.array([sgn * 0.0765, 1.628, -0.006])
        v, f = ellipsoid(np.zeros(3), np.array([0.0075, 0.027, 0.016]), 10, 14)
        tilt = np.radians(-12)
        c, s = np.cos(tilt), np.sin(tilt)
        v = v @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T + center
        bowl = gauss(v - [0, 0, 0], sgn * 0.082, 1.626, 0.005, 0.012) * (sgn * (v[:, 0] - center[0]) > 0)
        colors = np.array(COLORS["blush"]) * (1 - 0.25 * bowl)[:, None]
        parts.append(head_rigid(part("skin", v, f, np.zeros(0), colors)))
    return parts


def _brows() -> list[Part]:
    parts = []
    for sgn, side in ((1, "Left"), (-1, "Right")):
        tn = np.linspace(0, 1, 7)
        x = sgn * (0.010 + 0.037 * tn)
        y = EYES[0][1] + 0.021 + 0.0045 * np.sin(np.pi * tn * 0.9)
        keys = np.stack([x, y, surface_z(x, y) + 0.0015], 1)
        v, f, _ = loft(keys, np.full(7, 0.0018), 0.0036 - 0.0016 * tn, np.array([0, 1.0, 0]), 6, sub=2)
        brow = head_rigid(part("hair", v, f, np.zeros(0), COLORS["hair"]))
        t = np.clip((np.abs(v[:, 0]) - 0.010) / 0.037, 0.0, 1.0)
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


def _hairline(lon: np.ndarray) -> np.ndarray:
    """Hairline elevation (sine of latitude on the head) by longitude: high over the forehead,
    down at the temples, tufts before the ears, over the ears and low at the nape."""
    a = np.abs(np.angle(np.exp(1j * lon)))  # 0 at the forehead, pi at the nape
    edge = np.interp(
        a, [0.0, 0.5, 0.95, 1.25, 1.62, 2.1, 2.6, np.pi], [0.56, 0.52, 0.40, 0.30, 0.16, -0.28, -0.5, -0.58]
    )
    return edge - 0.14 * np.exp(-(((a - 1.32) / 0.12) ** 2))


HAIRLINE_Y = float(
    head_point(np.array([0.0, _hairline(np.zeros(1))[0], np.sqrt(1 - _hairline(np.zeros(1))[0] ** 2)]))[1]
)
"""Height of the hairline over the middle of the forehead."""


def _hair() -> Part:
    """Short hair with volume: a shell over the skull, thickest on top and swept up at the front,
    whose edge rolls in onto the scalp along the hairline; combed strands shade it."""
    rows, cols = 24, 72
    lon = np.linspace(-np.pi, np.pi, cols, endpoint=False)
    front = np.maximum(np.cos(lon), 0)
    edge = _hairline(lon)
    k = np.linspace(0, 1, rows - 1)[:, None] ** 0.9
    dy = 0.998 - (0.998 - edge[None]) * k
    c = np.sqrt(1 - dy**2)
    d = np.stack([c * np.sin(lon), dy, c * np.cos(lon)], -1)
    scalp = head_point(d)
    normal = normalize((scalp - HEAD_CENTER) / HEAD_RADII**2)
    top = smoothstep(0.0, 0.9, dy)
    sides = np.abs(np.sin(lon))[None] * smoothstep(0.35, 0.7, dy) * smoothstep(1.0, 0.75, dy)
    volume = 0.007 + 0.009 * top + 0.006 * sides + 0.005 * smoothstep(0.3, 0.8, dy) * front[None] ** 2
    volume *= 1 - 0.85 * smoothstep(0.45, 1.0, k) * (1 - 0.5 * front[None] ** 2)  # thinner toward the edge
    shell = scalp + normal * volume[..., None]
    rim = scalp[-1:] + normal[-1:] * 0.0008  # the edge turns in onto the scalp
    verts = np.concatenate([shell, rim]).reshape(-1, 3)
    faces = orient_outward(verts, grid_faces(rows, cols, wrap=True), HEAD_CENTER)
    strands = 0.86 + 0.14 * np.sin(lon * 47 + 1.7 * np.sin(lon * 9))[None] * (0.6 + 0.4 * np.sqrt(k))
    strands = np.concatenate([strands, strands[-1:]])
    shade = strands * np.concatenate([0.95 + 0.1 * top, 0.8 * np.ones((1, cols))])
    colors = np.array(COLORS["hair"]) * shade.reshape(-1, 1)
    return head_rigid(part("hair", verts, faces, np.zeros(0), colors))


def face_parts() -> list[Part]:
    """Every part of the head, morph targets attached."""
    return [head_part(), _lips(), *_mouth_inside(), *_eyes(), *_lids(), *_nose(), *_ears(), *_brows(), _hair()]


def face_landmarks() -> dict[str, np.ndarray]:
    """Rest positions the cameras and tests aim at."""
    return {
        "head": REST_POSITIONS[J["head"]].copy(),
        "mouth": np.array([0.0, MOUTH_Y, float(surface_z(0.0, MOUTH_Y))]),
        "left_eye": EYES[0].copy(),
        "right_eye": EYES[1].copy(),
        "nose": np.array([0.0, 1.592, float(surface_z(0.0, 1.592)) + 0.025]),
        "chin": np.array([0.0, MOUTH_Y - 0.04, float(surface_z(0.0, MOUTH_Y - 0.04))]),
        "brow": np.array([0.0, EYES[0][1] + 0.022, float(surface_z(0.0, EYES[0][1] + 0.022))]),
        "hairline": np.array([0.0, HAIRLINE_Y, float(surface_z(0.0, HAIRLINE_Y))]),
        "crown": np.array([0.0, HEAD_CENTER[1] + HEAD_RADII[1] + 0.025, HEAD_CENTER[2]]),
        "pelvis": REST_POSITIONS[J["pelvis"]].copy(),
    }
