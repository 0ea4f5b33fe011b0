"""Channel maps: canonical motion arrays to raw joint values, vectorised over time.

Every term of every joint becomes one column of a (T, K) matrix of raw quantities (an Euler angle
of a composed rotation, a blendshape weight, a root coordinate); mapped terms go through
``np.interp``; one (K, J) weight matrix then sums terms into joints, and gain, direction and offset
finish the job. A clip of thousands of frames is a handful of array operations.
"""

from __future__ import annotations

import numpy as np

from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.rotations import axis_angle_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.retargeting.profile_schema import JointMap, Term

AXIS = {"X": 0, "Y": 1, "Z": 2}


class ChannelMaps:
    """Evaluates a profile's joint maps (before smoothing and limits)."""

    def __init__(self, joints: tuple[JointMap, ...]) -> None:
        terms: list[Term] = [t for j in joints for t in j.terms]
        owner = [i for i, j in enumerate(joints) for _ in j.terms]
        self.num_joints = len(joints)
        self.weights = np.zeros((len(terms), len(joints)))
        for k, (t, j) in enumerate(zip(terms, owner)):
            self.weights[k, j] = t.weight
        scale = np.array([j.direction * j.gain for j in joints])
        self.weights *= scale[None, :]
        self.offset = np.array([j.offset for j in joints])

        # Rotation terms grouped by (chain, order): one Euler decomposition serves them all, and all
        # groups are decomposed together: chains padded with an identity slot to one length,
        # composed with a few batched matmuls, then split with per-group axis indices.
        groups: dict[tuple[tuple[str, ...], str], list[tuple[int, int]]] = {}
        for k, t in enumerate(terms):
            if t.kind == "rotation":
                groups.setdefault((t.chain, t.euler), []).append((k, t.axis))
        self.rotation_joints = sorted({JOINT_INDEX[n] for chain, _ in groups for n in chain})
        slot = {j: i for i, j in enumerate(self.rotation_joints)}
        identity = len(self.rotation_joints)
        depth = max((len(chain) for chain, _ in groups), default=0)
        self.chain_slots = np.array(
            [[slot[JOINT_INDEX[n]] for n in chain] + [identity] * (depth - len(chain)) for chain, _ in groups],
            dtype=int,
        ).reshape(len(groups), depth)
        order_idx = np.array([[AXIS[c] for c in order] for _, order in groups], dtype=int).reshape(len(groups), 3)
        self.ax_a, self.ax_b, self.ax_c = order_idx.T if len(groups) else (np.zeros(0, int),) * 3
        self.ax_sign = np.where((self.ax_b - self.ax_a) % 3 == 1, 1.0, -1.0)
        cols = [(g, k, axis) for g, cols_ in enumerate(groups.values()) for k, axis in cols_]
        self.rot_group = np.array([g for g, _, _ in cols], dtype=int)
        self.rot_col = np.array([k for _, k, _ in cols], dtype=int)
        self.rot_axis = np.array([a for _, _, a in cols], dtype=int)
        self.num_groups = len(groups)
        self.blend_cols = np.array([k for k, t in enumerate(terms) if t.kind == "blendshape"], dtype=int)
        self.blend_idx = np.array([BLENDSHAPE_INDEX[t.channel] for t in terms if t.kind == "blendshape"], dtype=int)
        self.trans_cols = np.array([k for k, t in enumerate(terms) if t.kind == "translation"], dtype=int)
        self.trans_idx = np.array([t.axis for t in terms if t.kind == "translation"], dtype=int)
        self.mapped = [
            (k, np.asarray(t.map_x), np.asarray(t.map_y)) for k, t in enumerate(terms) if t.map_x is not None
        ]
        self.num_terms = len(terms)

    def raw_terms(self, pose: np.ndarray, translation: np.ndarray, face: np.ndarray) -> np.ndarray:
        """(T, K) term values after their maps, before weights."""
        n = pose.shape[0]
        out = np.zeros((n, self.num_terms))
        if self.num_groups:
            mats = axis_angle_to_matrix(np.asarray(pose, np.float64)[:, self.rotation_joints])  # (T, R, 3, 3)
            mats = np.concatenate([mats, np.broadcast_to(np.eye(3), (n, 1, 3, 3))], axis=1)
            m = mats[:, self.chain_slots[:, 0]]
            for d in range(1, self.chain_slots.shape[1]):
                m = m @ mats[:, self.chain_slots[:, d]]
            out[:, self.rot_col] = self._euler(m)[:, self.rot_group, self.rot_axis]
        if self.blend_cols.size:
            out[:, self.blend_cols] = np.asarray(face, np.float64)[:, self.blend_idx]
        if self.trans_cols.size:
            out[:, self.trans_cols] = np.asarray(translation, np.float64)[:, self.trans_idx]
        for k, xs, ys in self.mapped:
            out[:, k] = np.interp(out[:, k], xs, ys)
        return out

    def _euler(self, m: np.ndarray) -> np.ndarray:
        """(T, G, 3) intrinsic Euler angles, each group in its own order (as rotations.matrix_to_euler)."""
        g = np.arange(self.num_groups)
        a, b, c, sign = self.ax_a, self.ax_b, self.ax_c, self.ax_sign
        sin_mid = np.clip(sign * m[:, g, a, c], -1.0, 1.0)
        t1 = np.arcsin(sin_mid)
        regular = np.sqrt(np.maximum(0.0, 1.0 - sin_mid**2)) > 1e-9
        t0 = np.arctan2(-sign * m[:, g, b, c], m[:, g, c, c])
        t2 = np.arctan2(-sign * m[:, g, a, b], m[:, g, a, a])
        if not regular.all():  # gimbal lock: all of the outer rotation goes into the first angle
            t0 = np.where(regular, t0, np.arctan2(sign * m[:, g, c, b], m[:, g, b, b]))
            t2 = np.where(regular, t2, 0.0)
        return np.stack([t0, t1, t2], axis=-1)

    def __call__(self, pose: np.ndarray, translation: np.ndarray, face: np.ndarray) -> np.ndarray:
        """(T, J) joint values: offset + direction * gain * sum(weight * map(term))."""
        return self.raw_terms(pose, translation, face) @ self.weights + self.offset
