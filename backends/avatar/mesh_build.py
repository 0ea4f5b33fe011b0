"""Small mesh primitives for the procedural avatar: lofted tubes, parametric grids, weights.

Everything here is plain NumPy on the rest pose; ``mannequin`` and ``mannequin_face`` compose
these into a body.
"""

from __future__ import annotations

import dataclasses

import numpy as np


def normalize(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    """Hermite ramp from 0 at ``edge0`` to 1 at ``edge1`` (either order)."""
    t = np.clip((np.asarray(x, float) - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def grid_faces(rows: int, cols: int, wrap: bool) -> np.ndarray:
    """Two triangles per cell of a rows x cols vertex grid; ``wrap`` closes the columns."""
    faces = []
    last = cols if wrap else cols - 1
    for r in range(rows - 1):
        for c in range(last):
            a, b = r * cols + c, r * cols + (c + 1) % cols
            d, e = a + cols, b + cols
            faces += [(a, b, e), (a, e, d)]
    return np.array(faces, dtype=np.int64).reshape(-1, 3)


def orient_outward(verts: np.ndarray, faces: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Flip faces whose normal points toward ``inside`` (a point per vertex, or one point)."""
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ref = inside[faces].mean(axis=1) if inside.ndim == 2 else inside
    flip = np.einsum("ij,ij->i", normal, tri.mean(axis=1) - ref) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return faces


def _superellipse(theta: np.ndarray, power: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(theta), np.sin(theta)
    e = 2.0 / power
    return np.sign(c) * np.abs(c) ** e, np.sign(s) * np.abs(s) ** e


def loft(
    keys: np.ndarray,
    ra: np.ndarray,
    rb: np.ndarray,
    ref: np.ndarray,
    segments: int,
    sub: int = 3,
    caps: tuple[bool, bool] = (True, True),
    power: float = 2.0,
    cap_length: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tube through ``keys`` with elliptical rings (radius ``rb`` toward ``ref``, ``ra`` across).

    Returns vertices, faces (outward) and each vertex's position along the keys (0 .. K-1),
    which ``chain_weights`` turns into bone weights.
    """
    keys = np.asarray(keys, float)
    k = len(keys)
    rho = np.concatenate([i + np.arange(sub) / sub for i in range(k - 1)] + [[k - 1.0]])
    idx = np.minimum(rho.astype(int), k - 2)
    frac = (rho - idx)[:, None]
    centers = keys[idx] * (1 - frac) + keys[idx + 1] * frac
    ras = np.interp(rho, np.arange(k), ra)
    rbs = np.interp(rho, np.arange(k), rb)
    tang = normalize(np.gradient(centers, axis=0))
    b = normalize(ref - np.einsum("ij,j->i", tang, ref)[:, None] * tang)
    a = np.cross(b, tang)
    cos_t, sin_t = _superellipse(np.linspace(0, 2 * np.pi, segments, endpoint=False), power)
    rings = (
        centers[:, None]
        + a[:, None] * (ras[:, None, None] * cos_t[None, :, None])
        + b[:, None] * (rbs[:, None, None] * sin_t[None, :, None])
    )
    verts = [rings.reshape(-1, 3)]
    axis = [np.repeat(centers, segments, axis=0)]
    rho_v = [np.repeat(rho, segments)]
    faces = [grid_faces(len(rho), segments, wrap=True)]
    count = len(rho) * segments
    for end, sign in ((0, -1.0), (len(rho) - 1, 1.0)):
        if not caps[0 if end == 0 else 1]:
            continue
        c, t, r = centers[end], tang[end] * sign, 0.5 * (ras[end] + rbs[end]) * cap_length
        ring_idx = np.arange(segments) + end * segments
        for phi in np.radians([40.0, 70.0]):
            scale = np.cos(phi)
            ring = (
                c
                + t * r * np.sin(phi)
                + a[end] * (ras[end] * scale * cos_t[:, None])
                + b[end] * (rbs[end] * scale * sin_t[:, None])
            )
            new_idx = np.arange(segments) + count
            verts.append(ring)
            axis.append(np.repeat(c[None], segments, axis=0))
            rho_v.append(np.full(segments, rho[end]))
            faces.append(_band(ring_idx, new_idx))
            ring_idx, count = new_idx, count + segments
        verts.append((c + t * r)[None])
        axis.append(c[None])
        rho_v.append([rho[end]])
        faces.append(np.stack([ring_idx, np.roll(ring_idx, -1), np.full(segments, count)], axis=1))
        count += 1
    v = np.concatenate(verts)
    f = orient_outward(v, np.concatenate(faces), np.concatenate(axis))
    return v, f, np.concatenate(rho_v)


def _band(ring_a: np.ndarray, ring_b: np.ndarray) -> np.ndarray:
    a1, b1 = np.roll(ring_a, -1), np.roll(ring_b, -1)
    return np.concatenate([np.stack([ring_a, a1, b1], 1), np.stack([ring_a, b1, ring_b], 1)])


def ellipsoid(center: np.ndarray, radii: np.ndarray, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed ellipsoid (poles on Y) with outward faces."""
    lat = np.linspace(-np.pi / 2, np.pi / 2, rows)[1:-1]
    lon = np.linspace(0, 2 * np.pi, cols, endpoint=False)
    d = np.stack(
        [
            np.cos(lat)[:, None] * np.sin(lon),
            np.repeat(np.sin(lat)[:, None], cols, 1),
            np.cos(lat)[:, None] * np.cos(lon),
        ],
        -1,
    ).reshape(-1, 3)
    verts = np.concatenate([d, [[0, -1, 0], [0, 1, 0]]]) * radii + center
    n = len(d)
    faces = [grid_faces(rows - 2, cols, wrap=True)]
    bottom, top = np.arange(cols), np.arange(cols) + n - cols
    faces.append(np.stack([bottom, np.roll(bottom, -1), np.full(cols, n)], 1))
    faces.append(np.stack([top, np.roll(top, -1), np.full(cols, n + 1)], 1))
    return verts, orient_outward(verts, np.concatenate(faces), np.asarray(center, float))


def chain_weights(
    rho: np.ndarray, owners: list[int], num_joints: int, before: int | None = None, blend: float = 0.3
) -> np.ndarray:
    """(N, J) weights for a loft: segment k belongs to ``owners[k]``; joints blend 50/50 at keys."""
    n_seg = len(owners)
    k = np.minimum(rho.astype(int), n_seg - 1)
    f = rho - k
    w = np.zeros((len(rho), num_joints))
    rows = np.arange(len(rho))
    prev = np.array([owners[i - 1] if i > 0 else (before if before is not None else owners[0]) for i in range(n_seg)])
    nxt = np.array([owners[i + 1] if i + 1 < n_seg else owners[i] for i in range(n_seg)])
    w_prev = np.where(f < blend, 0.5 * (1 - f / blend), 0.0)
    w_next = np.where(f > 1 - blend, 0.5 * (1 - (1 - f) / blend), 0.0)
    own = np.array(owners)[k]
    np.add.at(w, (rows, own), 1 - w_prev - w_next)
    np.add.at(w, (rows, prev[k]), w_prev)
    np.add.at(w, (rows, nxt[k]), w_next)
    return w


def ramp_weights(
    s: np.ndarray, owners: list[int], bounds: list[float], blend: list[float], num_joints: int
) -> np.ndarray:
    """(N, J) weights along a limb coordinate ``s``: ``owners[k]`` holds the stretch between
    ``bounds[k-1]`` and ``bounds[k]``; across each bound the next owner takes over by a smooth ramp
    ``blend[k]`` wide on either side."""
    s = np.asarray(s, float)
    past = [np.ones_like(s)] + [smoothstep(b - h, b + h, s) for b, h in zip(bounds, blend)] + [np.zeros_like(s)]
    w = np.zeros((len(s), num_joints))
    for k, joint in enumerate(owners):
        w[:, joint] += past[k] - past[k + 1]
    return w


def rigid_weights(count: int, joint: int, num_joints: int) -> np.ndarray:
    w = np.zeros((count, num_joints))
    w[:, joint] = 1.0
    return w


@dataclasses.dataclass
class Part:
    """One piece of the mannequin before assembly: a material's vertices, faces, skin weights over
    the canonical joints, vertex colours and its share of the morph targets."""

    material: str
    verts: np.ndarray  # (N, 3)
    faces: np.ndarray  # (F, 3), outward
    weights: np.ndarray  # (N, 55)
    colors: np.ndarray  # (N, 3) linear RGB
    deltas: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)  # ARKit name -> (N, 3)


def part(material: str, verts: np.ndarray, faces: np.ndarray, weights: np.ndarray, color: np.ndarray) -> Part:
    """A ``Part`` with one colour (3,) for every vertex, or a colour per vertex (N, 3)."""
    verts = np.asarray(verts, float)
    colors = np.broadcast_to(np.asarray(color, float), verts.shape).copy()
    return Part(material, verts, np.asarray(faces, np.int64), weights, colors)


def torus(
    center: np.ndarray, ring: tuple[float, float], minor: float, rows: int, cols: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ring (in the XZ plane, half-axes ``ring``) of round cross-section ``minor``: vertices,
    outward faces, and each vertex's angle around the ring."""
    u = np.linspace(0, 2 * np.pi, cols, endpoint=False)
    v = np.linspace(0, 2 * np.pi, rows, endpoint=False)
    axis = np.stack([ring[0] * np.sin(u), np.zeros_like(u), ring[1] * np.cos(u)], 1)
    out = normalize(np.stack([np.sin(u) / ring[0], np.zeros_like(u), np.cos(u) / ring[1]], 1))
    up = np.array([0.0, 1.0, 0.0])
    verts = (
        axis[:, None] + minor * np.cos(v)[None, :, None] * out[:, None] + minor * np.sin(v)[None, :, None] * up
    ).reshape(-1, 3) + center
    faces = []
    for i in range(cols):
        for j in range(rows):
            a, b = i * rows + j, i * rows + (j + 1) % rows
            c, d = ((i + 1) % cols) * rows + j, ((i + 1) % cols) * rows + (j + 1) % rows
            faces += [(a, b, d), (a, d, c)]
    inside = np.repeat(axis + center, rows, axis=0)
    return verts, orient_outward(verts, np.array(faces, np.int64), inside), np.repeat(u, rows)
