"""Pose a ``Rig`` from canonical motion: retarget rotations, morph targets, linear blend skinning.

Per frame: canonical forward kinematics gives each canonical joint's rotation away from its rest
(the canonical rest pose has no joint rotations, so a global rotation *is* that change); each rig
joint takes the change of the canonical joint it maps to, applied to its own rest orientation, so
bones of any length and local axes follow (``RigPoser.joint_world``). A rig whose rest pose is not
the canonical T-pose (an A-pose) is aligned bone by bone first (``rest_alignment``). Then one
small matmul adds the morph targets, one sparse (V x J) @ (J x 12) product blends the joint
transforms per vertex, and a sparse vertex-face sum gives smooth normals. No Python loop over
vertices.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from convodrive.backends.avatar.rig import Rig, Skeleton, csr, trs_matrix
from convodrive.motion.channels import BLENDSHAPE_INDEX, JAW_OPEN_RAD
from convodrive.motion.channels import EYE_LOOK_PITCH_RAD as GAZE_PITCH  # the joint-channel tie
from convodrive.motion.channels import EYE_LOOK_YAW_RAD as GAZE_YAW
from convodrive.motion.clip import MotionFrame
from convodrive.motion.rotations import axis_angle_to_matrix, euler_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX, REST_POSITIONS, forward_kinematics

if TYPE_CHECKING:
    import scipy.sparse as sp

_JAW = JOINT_INDEX["jaw"]
_EYES = (JOINT_INDEX["left_eye_smplhf"], JOINT_INDEX["right_eye_smplhf"])

# The child whose direction defines each canonical bone, for aligning a rig's rest pose to ours.
_AIM: dict[str, str] = {
    "pelvis": "spine1",
    "spine1": "spine2",
    "spine2": "spine3",
    "spine3": "neck",
    "neck": "head",
    **{f"{s}_{a}": f"{s}_{b}" for s in ("left", "right") for a, b in (("hip", "knee"), ("knee", "ankle"))},
    **{f"{s}_ankle": f"{s}_foot" for s in ("left", "right")},
    **{
        f"{s}_{a}": f"{s}_{b}"
        for s in ("left", "right")
        for a, b in (("collar", "shoulder"), ("shoulder", "elbow"), ("elbow", "wrist"), ("wrist", "middle1"))
    },
    **{
        f"{s}_{f}{i}": f"{s}_{f}{i + 1}"
        for s in ("left", "right")
        for f in ("thumb", "index", "middle", "ring", "pinky")
        for i in (1, 2)
    },
}
AIM_CHILD: dict[int, int] = {JOINT_INDEX[a]: JOINT_INDEX[b] for a, b in _AIM.items()}


def gaze_from_channels(face: np.ndarray) -> np.ndarray:
    """(2, 3, 3) eye rotations from the ``eyeLook*`` channels, for motion without eye joints."""
    out = np.empty((2, 3, 3))
    for i, (side, outward) in enumerate((("Left", 1.0), ("Right", -1.0))):
        ch = {k: float(face[BLENDSHAPE_INDEX[f"eyeLook{k}{side}"]]) for k in ("In", "Out", "Up", "Down")}
        yaw = outward * GAZE_YAW * (ch["Out"] - ch["In"])  # +yaw turns the eye toward +X (character's left)
        pitch = GAZE_PITCH * (ch["Down"] - ch["Up"])  # +X rotation tips the gaze down
        out[i] = euler_to_matrix(np.array([yaw, pitch, 0.0]), "YXZ")
    return out


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3x3) taking direction ``a`` to direction ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1 + 1e-9:  # opposite: half a turn about any axis normal to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def rest_alignment(skeleton: Skeleton, rest_world: np.ndarray) -> np.ndarray:
    """(J, 3, 3) per joint, the rotation that turns its rest bone direction into the canonical one.

    Identity for a rig in our own rest pose; for an A-pose rig it lifts the arms into the T-pose
    the canonical rotations start from. A joint with no aim child of its own (a head, a fingertip)
    keeps its parent's alignment, as it hangs from its parent in the rest pose.
    """
    by_canonical = {int(c): j for j, c in enumerate(skeleton.canonical) if c >= 0}
    align = np.tile(np.eye(3), (skeleton.num_joints, 1, 1))
    for j, c in enumerate(skeleton.canonical):
        p = skeleton.parents[j]
        if p >= 0:
            align[j] = align[p]
        if c < 0 or int(c) not in AIM_CHILD or AIM_CHILD[int(c)] not in by_canonical:
            continue
        child = by_canonical[AIM_CHILD[int(c)]]
        ours = rest_world[child, :3, 3] - rest_world[j, :3, 3]
        theirs = REST_POSITIONS[AIM_CHILD[int(c)]] - REST_POSITIONS[int(c)]
        if np.linalg.norm(ours) > 1e-6:
            align[j] = rotation_between(ours, theirs)
    return align


def _rotation_part(m: np.ndarray) -> np.ndarray:
    r = m[..., :3, :3]
    return r / np.linalg.norm(r, axis=-2, keepdims=True)


class RigPoser:
    """Turns canonical motion frames into posed vertices and normals for one ``Rig``."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        sk = rig.skeleton
        rest_world = sk.rest_world()
        self._rest_rot = _rotation_part(rest_world)
        self._align = rest_alignment(sk, rest_world)
        self._canonical = [int(c) for c in sk.canonical]
        mapped = {c: j for j, c in enumerate(self._canonical) if c >= 0}
        self.root_joint = mapped.get(0, -1)
        height = rest_world[self.root_joint, 1, 3] if self.root_joint >= 0 else REST_POSITIONS[0, 1]
        self.translation_scale = float(height / REST_POSITIONS[0, 1]) if height > 0.05 else 1.0
        self._locals = [
            (sk.translation[j].copy(), sk.rotation[j].copy(), sk.scale[j].copy()) for j in range(sk.num_joints)
        ]
        self._morph_columns = np.array([BLENDSHAPE_INDEX[n] for n in rig.morph_names], dtype=int)
        self._jaw_morph = rig.morph_names.index("jawOpen") if "jawOpen" in rig.morph_names else -1
        self._deltas = rig.morph_deltas.reshape(len(rig.morph_names), 3 * len(rig.morph_index)).astype(np.float32)
        self._rest = rig.rest.astype(np.float32)
        self._weights = rig.weights.astype(np.float32)
        self._faces = np.concatenate([s.faces.astype(np.int64) + s.start for s in rig.surfaces])
        self._normal_sum = welded_incidence(rig.rest, rig.normals, self._faces).astype(np.float32)

    def canonical_rotations(self, frame: MotionFrame) -> np.ndarray:
        """(55, 3, 3) local rotations: gaze filled from channels when the eye joints are still, and
        the jaw held shut when a ``jawOpen`` morph target opens the mouth (never twice)."""
        local = axis_angle_to_matrix(np.asarray(frame.pose, float))
        if not np.any(np.abs(frame.pose[list(_EYES)]) > 1e-6):
            local[list(_EYES)] = gaze_from_channels(frame.face)
        if self._jaw_morph >= 0:
            local[_JAW] = np.eye(3)
        return local

    def joint_world(self, frame: MotionFrame) -> np.ndarray:
        """(J, 4, 4) posed world transforms of the rig's joints."""
        change, _ = forward_kinematics(self.canonical_rotations(frame))
        sk = self.rig.skeleton
        world = np.empty((sk.num_joints, 4, 4))
        orient = np.empty((sk.num_joints, 3, 3))
        shift = np.asarray(frame.translation, float) * self.translation_scale
        for j, p in enumerate(sk.parents):
            t, r, s = self._locals[j]
            parent_orient = orient[p] if p >= 0 else np.eye(3)
            c = self._canonical[j]
            if c >= 0:
                orient[j] = change[c] @ self._align[j] @ self._rest_rot[j]
                r = parent_orient.T @ orient[j]
            else:
                orient[j] = parent_orient @ r
            local = trs_matrix(t, r, s)
            world[j] = local if p < 0 else world[p] @ local
            if j == self.root_joint:
                world[j, :3, 3] += shift
        return world

    def morph_weights(self, frame: MotionFrame) -> np.ndarray:
        """Weights of the rig's morph targets; the jaw joint's opening counts as ``jawOpen``."""
        w = np.clip(np.asarray(frame.face, float)[self._morph_columns], 0.0, 1.0)
        if self._jaw_morph >= 0:
            jaw = float(np.clip(frame.pose[_JAW][0] / JAW_OPEN_RAD, 0.0, 1.0))
            w[self._jaw_morph] = max(w[self._jaw_morph], jaw)
        return w

    def skin_matrices(self, frame: MotionFrame) -> np.ndarray:
        """(J, 12): each joint's bind-to-posed transform, its top three rows flattened."""
        m = self.joint_world(frame) @ self.rig.skeleton.inverse_bind
        return m[:, :3, :].reshape(len(m), 12)

    def pose(self, frame: MotionFrame) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices and unit normals, (V, 3) float32 each. Single precision throughout: a
        tenth of a micrometre on a human-sized body, at half the memory traffic."""
        shaped = self._rest.copy()
        if len(self._deltas):
            w = self.morph_weights(frame)
            active = np.flatnonzero(w > 1e-4)  # a face uses a few channels at a time
            if len(active):
                shaped[self.rig.morph_index] += (w[active].astype(np.float32) @ self._deltas[active]).reshape(-1, 3)
        m = np.asarray(self._weights @ self.skin_matrices(frame).astype(np.float32))  # (V, 12) rows of [R | t]
        x, y, z = shaped[:, 0:1], shaped[:, 1:2], shaped[:, 2:3]
        verts = m[:, 0::4] * x + m[:, 1::4] * y + m[:, 2::4] * z + m[:, 3::4]
        return verts, self.normals(verts)

    def normals(self, verts: np.ndarray) -> np.ndarray:
        return vertex_normals(verts, self._faces, self._normal_sum)


def vertex_normals(verts: np.ndarray, faces: np.ndarray, vertex_faces: sp.csr_matrix) -> np.ndarray:
    """Unit normals: area-weighted face normals summed over ``vertex_faces`` (V x F)."""
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    u, v = b - a, c - a
    face_n = np.stack(
        [
            u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
            u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
            u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0],
        ],
        1,
    )
    n = np.asarray(vertex_faces @ face_n)
    length = np.sqrt((n * n).sum(1, keepdims=True))
    return np.where(length > 1e-12, n / np.maximum(length, 1e-12), np.array([0.0, 0.0, 1.0], n.dtype)).astype(
        verts.dtype
    )


def incidence(num_vertices: int, faces: np.ndarray) -> sp.csr_matrix:
    """(V, F) 1 where a vertex is a corner of a face."""
    f = len(faces)
    return csr(np.ones(3 * f), faces.ravel(), np.repeat(np.arange(f), 3), (num_vertices, f))


def welded_incidence(points: np.ndarray, normals: np.ndarray | None, faces: np.ndarray) -> sp.csr_matrix:
    """(V, F) which faces shade each vertex. Vertices at one rest position whose rest normals
    agree (a texture seam, a sleeve meeting a hand) share their faces, so no seam shows; a
    deliberate hard edge (normals apart) stays hard."""
    v = len(points)
    plain = incidence(v, faces)
    group = weld_groups(points, normals)
    if group is None:
        return plain
    weld = csr(np.ones(v), np.arange(v), group, (v, v))
    return weld @ (weld.T @ plain)


def smooth_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Rest normals for a mesh that brings none: smooth, and shared where vertices coincide."""
    points = np.asarray(points, float)
    own = vertex_normals(points, faces, incidence(len(points), faces))
    return vertex_normals(points, faces, welded_incidence(points, own, faces))


def weld_groups(points: np.ndarray, normals: np.ndarray | None, tol: float = 1e-5) -> np.ndarray | None:
    """(V,) a group id per vertex, shared by coincident vertices with agreeing normals; None when
    no two vertices coincide."""
    keys = np.round(np.asarray(points, float) / tol).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    if len(first) == len(points):
        return None
    group = first[inverse]
    if normals is not None:  # split a position's vertices whose normals disagree with its first
        n = np.asarray(normals, float)
        apart = np.einsum("ij,ij->i", n, n[group]) < 0.5
        group = np.where(apart, np.arange(len(points)), group)
    return group
