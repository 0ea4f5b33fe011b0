"""Channel maps: canonical motion arrays to raw joint values, vectorised over time.

Every term of every joint becomes one column of a (T, K) matrix of raw quantities (an Euler angle
of a composed rotation, a blendshape weight, a root coordinate); mapped terms go through
``np.interp``; one (K, J) weight matrix then sums terms into joints, and gain, direction and offset
finish the job. A clip of thousands of frames is a handful of array operations.
"""

from __future__ import annotations

import numpy as np

from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.rotations import axis_angle_to_matrix, matrix_to_euler
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.retargeting.profile import JointMap, Term


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

        # Rotation terms grouped by (chain, order): one Euler decomposition serves them all.
        groups: dict[tuple[tuple[str, ...], str], list[tuple[int, int]]] = {}
        for k, t in enumerate(terms):
            if t.kind == "rotation":
                groups.setdefault((t.chain, t.euler), []).append((k, t.axis))
        self.rotation_groups = [
            ([JOINT_INDEX[n] for n in chain], order, np.array([k for k, _ in cols]), np.array([a for _, a in cols]))
            for (chain, order), cols in groups.items()
        ]
        self.rotation_joints = sorted({j for chain, *_ in self.rotation_groups for j in chain})
        self._slot = {j: i for i, j in enumerate(self.rotation_joints)}
        self.blend_cols = np.array([k for k, t in enumerate(terms) if t.kind == "blendshape"], dtype=int)
        self.blend_idx = np.array([BLENDSHAPE_INDEX[t.channel] for t in terms if t.kind == "blendshape"], dtype=int)
        self.trans_cols = np.array([k for k, t in enumerate(terms) if t.kind == "translation"], dtype=int)
        self.trans_idx = np.array([t.axis for t in terms if t.kind == "translation"], dtype=int)
        self.mapped = [(k, np.asarray(t.map_x), np.asarray(t.map_y)) for k, t in enumerate(terms) if t.map_x is not None]
        self.num_terms = len(terms)

    def raw_terms(self, pose: np.ndarray, translation: np.ndarray, face: np.ndarray) -> np.ndarray:
        """(T, K) term values after their maps, before weights."""
        n = pose.shape[0]
        out = np.zeros((n, self.num_terms))
        if self.rotation_groups:
            mats = axis_angle_to_matrix(np.asarray(pose, np.float64)[:, self.rotation_joints])  # (T, R, 3, 3)
            for chain, order, cols, axes in self.rotation_groups:
                m = mats[:, self._slot[chain[0]]]
                for j in chain[1:]:
                    m = m @ mats[:, self._slot[j]]
                out[:, cols] = matrix_to_euler(m, order)[:, axes]
        if self.blend_cols.size:
            out[:, self.blend_cols] = np.asarray(face, np.float64)[:, self.blend_idx]
        if self.trans_cols.size:
            out[:, self.trans_cols] = np.asarray(translation, np.float64)[:, self.trans_idx]
        for k, xs, ys in self.mapped:
            out[:, k] = np.interp(out[:, k], xs, ys)
        return out

    def __call__(self, pose: np.ndarray, translation: np.ndarray, face: np.ndarray) -> np.ndarray:
        """(T, J) joint values: offset + direction * gain * sum(weight * map(term))."""
        return self.raw_terms(pose, translation, face) @ self.weights + self.offset
