"""Pose the avatar: blendshapes, eyelids and gaze, then linear blend skinning, all vectorised.

Per frame: one small matmul adds the face blendshapes, eyelids are placed on their spheres, forward
kinematics gives every joint's transform, one sparse (V x 55) @ (55 x 12) product blends them per
vertex, and a sparse vertex-face sum gives smooth normals. No Python loop over vertices.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from convodrive.backends.avatar.avatar_mesh import LID_REST_EDGES, SHAPES, Avatar, lid_positions
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.channels import EYE_LOOK_PITCH_RAD as GAZE_PITCH  # the joint-channel tie
from convodrive.motion.channels import EYE_LOOK_YAW_RAD as GAZE_YAW
from convodrive.motion.channels import JAW_OPEN_RAD as JAW_RAD_AT_FULL_OPEN
from convodrive.motion.clip import MotionFrame
from convodrive.motion.rotations import axis_angle_to_matrix, euler_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX, REST_POSITIONS, forward_kinematics

_SHAPE_COLUMNS = np.array([BLENDSHAPE_INDEX[name] for name in SHAPES])
_JAW = JOINT_INDEX["jaw"]
_EYES = (JOINT_INDEX["left_eye_smplhf"], JOINT_INDEX["right_eye_smplhf"])


def skinning_matrices(rotations: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(55, 12): each joint's rest-to-posed transform [R | p - R r], flattened row-major."""
    t = positions - np.einsum("jab,jb->ja", rotations, REST_POSITIONS)
    return np.concatenate([rotations, t[:, :, None]], axis=2).reshape(len(rotations), 12)


def linear_blend_skinning(
    points: np.ndarray, weights: sp.csr_matrix, rotations: np.ndarray, positions: np.ndarray
) -> np.ndarray:
    """Skin rest-pose ``points`` (V, 3) with ``weights`` (V, 55) by global joint transforms."""
    blended = np.asarray(weights @ skinning_matrices(rotations, positions)).reshape(-1, 3, 4)
    return np.einsum("vab,vb->va", blended[:, :, :3], points) + blended[:, :, 3]


def gaze_from_channels(face: np.ndarray) -> np.ndarray:
    """(2, 3, 3) eye rotations from the ``eyeLook*`` channels, for motion without eye joints."""
    out = np.empty((2, 3, 3))
    for i, (side, outward) in enumerate((("Left", 1.0), ("Right", -1.0))):
        ch = {k: float(face[BLENDSHAPE_INDEX[f"eyeLook{k}{side}"]]) for k in ("In", "Out", "Up", "Down")}
        yaw = outward * GAZE_YAW * (ch["Out"] - ch["In"])  # +yaw turns the eye toward +X (character's left)
        pitch = GAZE_PITCH * (ch["Down"] - ch["Up"])  # +X rotation tips the gaze down
        out[i] = euler_to_matrix(np.array([yaw, pitch, 0.0]), "YXZ")
    return out


class AvatarPoser:
    """Turns canonical motion frames into posed vertices and normals for one ``Avatar``."""

    def __init__(self, avatar: Avatar) -> None:
        self.avatar = avatar
        faces = avatar.faces.astype(np.int64)
        v, f = avatar.num_vertices, len(faces)
        self._vertex_faces = sp.csr_matrix((np.ones(3 * f), (faces.ravel(), np.repeat(np.arange(f), 3))), shape=(v, f))
        self._faces = faces
        self._deltas = avatar.shape_deltas.reshape(len(SHAPES), -1)
        lids = avatar.lids
        self._lid_args = (lids.eye, lids.psi, lids.start, lids.t, lids.radius)

    def joint_transforms(self, frame: MotionFrame) -> tuple[np.ndarray, np.ndarray]:
        """Global joint rotations (55, 3, 3) and positions (55, 3), gaze filled from channels if needed."""
        local = axis_angle_to_matrix(np.asarray(frame.pose, float))
        if not np.any(np.abs(frame.pose[list(_EYES)]) > 1e-6):
            local[list(_EYES)] = gaze_from_channels(frame.face)
        return forward_kinematics(local, np.asarray(frame.translation, float))

    def face_weights(self, frame: MotionFrame) -> np.ndarray:
        """Blendshape weights in ``SHAPES`` order; the jaw joint's opening counts as ``jawOpen``."""
        w = np.clip(np.asarray(frame.face, float)[_SHAPE_COLUMNS], 0.0, 1.0)
        jaw_pitch = float(frame.pose[_JAW][0])
        w[0] = max(w[0], float(np.clip(jaw_pitch / JAW_RAD_AT_FULL_OPEN, 0.0, 1.0)))
        return w

    def lid_edges(self, frame: MotionFrame, eye_rotations: np.ndarray) -> np.ndarray:
        """Edge elevations (left upper, left lower, right upper, right lower), radians.

        Lids close with ``eyeBlink*``, open with ``eyeWide*``, narrow with ``eyeSquint*`` and
        follow the eye's pitch, as real lids do when someone looks down.
        """
        face = frame.face
        edges = LID_REST_EDGES.copy()
        for i, side in enumerate(("Left", "Right")):
            blink, wide, squint = (float(face[BLENDSHAPE_INDEX[f"eye{k}{side}"]]) for k in ("Blink", "Wide", "Squint"))
            pitch = float(np.arcsin(np.clip(eye_rotations[i][1, 2], -1, 1)))  # forward's Y: up is positive
            edges[2 * i] = np.clip(
                edges[2 * i] + np.radians(12) * wide - np.radians(52) * blink - np.radians(10) * squint + 0.7 * pitch,
                np.radians(-29),
                np.radians(45),
            )
            edges[2 * i + 1] = np.clip(
                edges[2 * i + 1] + np.radians(12) * squint + 0.3 * pitch, np.radians(-45), np.radians(-16)
            )
        return edges

    def pose(self, frame: MotionFrame) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices and unit normals, (V, 3) float32 each."""
        av = self.avatar
        rest = av.rest.astype(np.float64)
        shaped = rest.copy()
        shaped[av.shape_index] += (self.face_weights(frame) @ self._deltas).reshape(-1, 3)
        rotations, positions = self.joint_transforms(frame)
        head = rotations[JOINT_INDEX["head"]]
        eye_local = [head.T @ rotations[e] for e in _EYES]
        shaped[av.lids.index] = lid_positions(*self._lid_args, self.lid_edges(frame, eye_local), av.lids.upper)
        verts = linear_blend_skinning(shaped, av.weights, rotations, positions)
        return verts.astype(np.float32), self.normals(verts).astype(np.float32)

    def normals(self, verts: np.ndarray) -> np.ndarray:
        tri = verts[self._faces]
        face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # area-weighted
        n = np.asarray(self._vertex_faces @ face_n)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 1e-12, n / np.maximum(length, 1e-12), [0.0, 0.0, 1.0])
