"""The canonical skeleton: SMPL-X's 55 joint names and parents, with our own rest pose.

Coordinates are metres, Y up, the character facing +Z, so its left side is +X (the SMPL-X
convention, which keeps data-set converters simple). The rest pose is a T-pose of a neutral adult
about 1.75 m tall that we measured out ourselves; no licensed body model is needed.
"""

from __future__ import annotations

import numpy as np

JOINT_NAMES: tuple[str, ...] = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "jaw",
    "left_eye_smplhf",
    "right_eye_smplhf",
    "left_index1",
    "left_index2",
    "left_index3",
    "left_middle1",
    "left_middle2",
    "left_middle3",
    "left_pinky1",
    "left_pinky2",
    "left_pinky3",
    "left_ring1",
    "left_ring2",
    "left_ring3",
    "left_thumb1",
    "left_thumb2",
    "left_thumb3",
    "right_index1",
    "right_index2",
    "right_index3",
    "right_middle1",
    "right_middle2",
    "right_middle3",
    "right_pinky1",
    "right_pinky2",
    "right_pinky3",
    "right_ring1",
    "right_ring2",
    "right_ring3",
    "right_thumb1",
    "right_thumb2",
    "right_thumb3",
)
NUM_JOINTS = len(JOINT_NAMES)
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}

_BODY_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15)


def _finger_parents() -> tuple[int, ...]:
    parents: list[int] = []
    for wrist in (20, 21):
        for _finger in range(5):
            base = len(_BODY_PARENTS) + len(parents)
            parents += [wrist, base, base + 1]
    return tuple(parents)


PARENTS: tuple[int, ...] = _BODY_PARENTS + _finger_parents()

# World positions of the left half and the midline in the rest T-pose; the right half mirrors X.
_REST_WORLD_LEFT: dict[str, tuple[float, float, float]] = {
    "pelvis": (0.0, 0.95, 0.0),
    "left_hip": (0.088, 0.88, -0.005),
    "spine1": (0.0, 1.06, -0.015),
    "left_knee": (0.100, 0.50, 0.005),
    "spine2": (0.0, 1.19, -0.005),
    "left_ankle": (0.105, 0.09, -0.030),
    "spine3": (0.0, 1.25, 0.005),
    "left_foot": (0.115, 0.025, 0.095),
    "neck": (0.0, 1.48, -0.015),
    "left_collar": (0.070, 1.39, -0.010),
    "head": (0.0, 1.56, 0.010),
    "left_shoulder": (0.180, 1.41, -0.025),
    "left_elbow": (0.445, 1.41, -0.035),
    "left_wrist": (0.700, 1.41, -0.030),
    "jaw": (0.0, 1.545, 0.045),
    "left_eye_smplhf": (0.032, 1.635, 0.085),
    "left_index1": (0.790, 1.41, 0.000),
    "left_index2": (0.830, 1.41, 0.000),
    "left_index3": (0.855, 1.41, 0.000),
    "left_middle1": (0.795, 1.41, -0.022),
    "left_middle2": (0.840, 1.41, -0.022),
    "left_middle3": (0.868, 1.41, -0.022),
    "left_pinky1": (0.775, 1.405, -0.060),
    "left_pinky2": (0.805, 1.405, -0.060),
    "left_pinky3": (0.825, 1.405, -0.060),
    "left_ring1": (0.790, 1.408, -0.041),
    "left_ring2": (0.832, 1.408, -0.041),
    "left_ring3": (0.858, 1.408, -0.041),
    "left_thumb1": (0.725, 1.395, 0.025),
    "left_thumb2": (0.755, 1.390, 0.045),
    "left_thumb3": (0.785, 1.388, 0.060),
}


def _rest_world() -> np.ndarray:
    pos = np.zeros((NUM_JOINTS, 3))
    for i, name in enumerate(JOINT_NAMES):
        if name in _REST_WORLD_LEFT:
            pos[i] = _REST_WORLD_LEFT[name]
        else:
            mirror = name.replace("right_", "left_")
            x, y, z = _REST_WORLD_LEFT[mirror]
            pos[i] = (-x, y, z)
    return pos


REST_POSITIONS: np.ndarray = _rest_world()
"""(55, 3) world joint positions of the rest pose, metres."""
REST_OFFSETS: np.ndarray = np.array(
    [REST_POSITIONS[i] - (REST_POSITIONS[p] if p >= 0 else 0.0) for i, p in enumerate(PARENTS)]
)
"""(55, 3) bone offsets from each joint's parent; the root's is its rest position."""
REST_POSITIONS.setflags(write=False)
REST_OFFSETS.setflags(write=False)


def children(joint: int) -> list[int]:
    return [i for i, p in enumerate(PARENTS) if p == joint]


def chain_to_root(joint: int) -> list[int]:
    """The joints from the root down to ``joint``, inclusive."""
    chain = []
    while joint >= 0:
        chain.append(joint)
        joint = PARENTS[joint]
    return chain[::-1]


def global_rotation(rotmats: np.ndarray, joint: int) -> np.ndarray:
    """(..., 3, 3) world orientation of one joint from local rotations (..., 55, 3, 3).

    Walks only the joint's chain to the root, so a head or wrist costs a few matmuls, not 55.
    """
    chain = chain_to_root(joint)
    glob = rotmats[..., chain[0], :, :]
    for j in chain[1:]:
        glob = glob @ rotmats[..., j, :, :]
    return glob


def forward_kinematics(
    rotmats: np.ndarray, root_translation: np.ndarray | None = None, offsets: np.ndarray = REST_OFFSETS
) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (..., 55, 3, 3) and positions (..., 55, 3) from local rotation matrices.

    ``root_translation`` (..., 3) displaces the root from its rest position.
    """
    batch = rotmats.shape[:-3]
    glob_r = np.empty(batch + (NUM_JOINTS, 3, 3))
    glob_p = np.empty(batch + (NUM_JOINTS, 3))
    for j, p in enumerate(PARENTS):
        if p < 0:
            glob_r[..., j, :, :] = rotmats[..., j, :, :]
            glob_p[..., j, :] = offsets[j] + (0.0 if root_translation is None else root_translation)
        else:
            glob_r[..., j, :, :] = glob_r[..., p, :, :] @ rotmats[..., j, :, :]
            glob_p[..., j, :] = glob_p[..., p, :] + np.einsum("...ij,j->...i", glob_r[..., p, :, :], offsets[j])
    return glob_r, glob_p
