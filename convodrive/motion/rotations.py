"""Rotation conversions between axis-angle, unit quaternions (w, x, y, z), matrices, 6D and Euler.

All functions are vectorised over leading axes and return float64. The 6D form (Zhou et al. 2019)
is the first two *rows* of the matrix, PyTorch3D's ``matrix_to_rotation_6d`` convention, which is
how ProbTalk and EMAGE store poses, so their 6D arrays convert without a transpose. Euler angles are intrinsic
rotations in the order written: ``"ZXY"`` means R = Rz @ Rx @ Ry, which is how BVH channel lists
(Zrotation Xrotation Yrotation) compose.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def _as_float(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def axis_angle_to_quat(aa: np.ndarray) -> np.ndarray:
    aa = _as_float(aa)
    angle = np.linalg.norm(aa, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle with its Taylor series near zero, so tiny rotations stay exact.
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half), aa * k], axis=-1)


def quat_to_axis_angle(q: np.ndarray) -> np.ndarray:
    q = _as_float(q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., :1] < 0, -q, q)  # the shorter way round: angle in [0, pi]
    xyz = q[..., 1:]
    s = np.linalg.norm(xyz, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    small = s < 1e-7
    k = np.where(small, 2.0 / np.clip(q[..., :1], _EPS, None), angle / np.where(small, 1.0, s))
    return xyz * k


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    q = _as_float(q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Shepperd's method: pick the largest of w, x, y, z to divide by, for stability."""
    m = _as_float(m)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    cands = np.stack(
        [
            np.stack(
                [
                    1 + m00 + m11 + m22,
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m00 - m11 - m22,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m00 + m11 - m22,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        axis=-2,
    )
    diag = np.stack([m00 + m11 + m22, m00, m11, m22], axis=-1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def axis_angle_to_matrix(aa: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, expanded entry by entry: cos(t) I + sin(t)/t K + (1 - cos(t))/t^2 v v^T
    for v = t * axis and K its cross-product matrix (a batched ``K @ K`` took twice as long; this
    runs for every training window)."""
    aa = _as_float(aa)
    theta2 = np.einsum("...i,...i->...", aa, aa)
    angle = np.sqrt(theta2)
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(angle) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(angle)) / (safe * safe))
    x, y, z = np.moveaxis(aa, -1, 0)
    c = 1.0 - b * theta2
    bx, by, bz = b * x, b * y, b * z
    ax, ay, az = a * x, a * y, a * z
    entries = [
        [c + bx * x, bx * y - az, bx * z + ay],
        [bx * y + az, c + by * y, by * z - ax],
        [bx * z - ay, by * z + ax, c + bz * z],
    ]
    return np.stack([np.stack(row, axis=-1) for row in entries], axis=-2)


def matrix_to_axis_angle(m: np.ndarray) -> np.ndarray:
    return quat_to_axis_angle(matrix_to_quat(m))


def matrix_to_6d(m: np.ndarray) -> np.ndarray:
    """(..., 6): rows 0 and 1 of the matrix, concatenated (PyTorch3D's order)."""
    m = _as_float(m)
    return np.concatenate([m[..., 0, :], m[..., 1, :]], axis=-1)


def sixd_to_matrix(d6: np.ndarray) -> np.ndarray:
    """Gram-Schmidt on the two stored rows; any 6-vector of two independent rows is valid."""
    d6 = _as_float(d6)
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / np.linalg.norm(a1, axis=-1, keepdims=True)
    b2 = a2 - np.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 = b2 / np.linalg.norm(b2, axis=-1, keepdims=True)
    b3 = np.cross(b1, b2)
    return np.stack([b1, b2, b3], axis=-2)


def axis_angle_to_6d(aa: np.ndarray) -> np.ndarray:
    return matrix_to_6d(axis_angle_to_matrix(aa))


def sixd_to_axis_angle(d6: np.ndarray) -> np.ndarray:
    return matrix_to_axis_angle(sixd_to_matrix(d6))


_AXIS = {"X": 0, "Y": 1, "Z": 2}


def _elementary(axis: str, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    if axis == "X":
        rows = [one, zero, zero, zero, c, -s, zero, s, c]
    elif axis == "Y":
        rows = [c, zero, s, zero, one, zero, -s, zero, c]
    else:
        rows = [c, -s, zero, s, c, zero, zero, zero, one]
    return np.stack(rows, axis=-1).reshape(angle.shape + (3, 3))


def _check_order(order: str) -> str:
    order = order.upper()
    if len(order) != 3 or set(order) != {"X", "Y", "Z"}:
        raise ValueError(f"Euler order must be a permutation of XYZ, got {order!r}")
    return order


def euler_to_matrix(angles: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles (..., 3), the i-th angle about the i-th axis of ``order``."""
    order = _check_order(order)
    angles = _as_float(angles)
    m = _elementary(order[0], angles[..., 0])
    for i in (1, 2):
        m = m @ _elementary(order[i], angles[..., i])
    return m


def matrix_to_euler(m: np.ndarray, order: str) -> np.ndarray:
    """Inverse of :func:`euler_to_matrix`; the middle angle is in [-pi/2, pi/2].

    For R = R_a(t0) R_b(t1) R_c(t2) with (a, b, c) a permutation and sign s of that permutation,
    sin(t1) = s * R[a, c]; the outer angles come from the row a and the column c.
    """
    order = _check_order(order)
    m = _as_float(m)
    a, b, c = (_AXIS[ch] for ch in order)
    sign = 1.0 if (b - a) % 3 == 1 else -1.0
    sin_mid = np.clip(sign * m[..., a, c], -1.0, 1.0)
    t1 = np.arcsin(sin_mid)
    cos_mid = np.sqrt(np.maximum(0.0, 1.0 - sin_mid**2))
    regular = cos_mid > 1e-9
    t0 = np.arctan2(-sign * m[..., b, c], m[..., c, c])
    t2 = np.arctan2(-sign * m[..., a, b], m[..., a, a])
    # Gimbal lock: put all of the outer rotation into the first angle.
    t0_lock = np.arctan2(sign * m[..., c, b], m[..., b, b])
    t0 = np.where(regular, t0, t0_lock)
    t2 = np.where(regular, t2, 0.0)
    return np.stack([t0, t1, t2], axis=-1)


def axis_angle_to_euler(aa: np.ndarray, order: str) -> np.ndarray:
    return matrix_to_euler(axis_angle_to_matrix(aa), order)


def euler_to_axis_angle(angles: np.ndarray, order: str) -> np.ndarray:
    return matrix_to_axis_angle(euler_to_matrix(angles, order))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = _as_float(a), _as_float(b)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    a, b = _as_float(a), _as_float(b)
    t = np.asarray(t, dtype=np.float64)[..., None] if np.ndim(t) else float(t)
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    near = sin_t < 1e-6
    wa = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(near, 1.0, sin_t))
    wb = np.where(near, t, np.sin(t * theta) / np.where(near, 1.0, sin_t))
    q = wa * a + wb * b
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
