"""Canonical motion core: rotation conversions, the skeleton, and the .npz clip format."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from convodrive.motion import rotations as rot
from convodrive.motion.clip import MotionClip
from convodrive.motion.npz import FORMAT_VERSION, load_clip, save_clip
from convodrive.motion.skeleton import (
    JOINT_NAMES,
    NUM_JOINTS,
    PARENTS,
    REST_OFFSETS,
    REST_POSITIONS,
    forward_kinematics,
)
from convodrive.plumbing.errors import InputFileError

ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]


def sample_axis_angles(n: int = 400, seed: int = 0) -> np.ndarray:
    """Random rotations plus the hard cases: zero, tiny, and angles at and near pi."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate(
        [
            rng.uniform(0, np.pi, n - 60),
            np.zeros(5),
            np.full(15, 1e-9),
            np.full(10, 1e-5),
            np.full(15, np.pi - 1e-7),
            np.full(15, np.pi),
        ]
    )
    return axes * angles[:, None]


def same_rotation(a: np.ndarray, b: np.ndarray, tol: float = 1e-7) -> None:
    """Compare rotations as matrices: axis-angle at pi has two equal spellings (v and -v)."""
    np.testing.assert_allclose(rot.axis_angle_to_matrix(a), rot.axis_angle_to_matrix(b), atol=tol)


def test_matrix_agrees_with_scipy() -> None:
    aa = sample_axis_angles()
    np.testing.assert_allclose(rot.axis_angle_to_matrix(aa), Rotation.from_rotvec(aa).as_matrix(), atol=1e-12)
    q = rot.axis_angle_to_quat(aa)
    np.testing.assert_allclose(
        np.abs(np.sum(q * Rotation.from_rotvec(aa).as_quat(scalar_first=True), axis=1)), 1, atol=1e-12
    )


def test_axis_angle_quat_matrix_round_trips() -> None:
    aa = sample_axis_angles()
    back = rot.quat_to_axis_angle(rot.axis_angle_to_quat(aa))
    small = np.linalg.norm(aa, axis=1) < np.pi - 1e-3
    np.testing.assert_allclose(back[small], aa[small], atol=1e-9)  # exact away from pi, tiny ones too
    same_rotation(back, aa)
    same_rotation(rot.matrix_to_axis_angle(rot.axis_angle_to_matrix(aa)), aa)
    assert np.all(np.linalg.norm(rot.matrix_to_axis_angle(rot.axis_angle_to_matrix(aa)), axis=1) <= np.pi + 1e-9)
    q = rot.axis_angle_to_quat(aa)
    m = rot.quat_to_matrix(q)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    q2 = rot.matrix_to_quat(m)
    np.testing.assert_allclose(np.abs(np.sum(q * q2, axis=1)), 1.0, atol=1e-9)


def test_tiny_angles_keep_their_precision() -> None:
    aa = np.array([[1e-9, -2e-9, 3e-9], [1e-7, 0, 0]])
    np.testing.assert_allclose(rot.quat_to_axis_angle(rot.axis_angle_to_quat(aa)), aa, rtol=1e-6, atol=0)
    np.testing.assert_allclose(rot.matrix_to_axis_angle(rot.axis_angle_to_matrix(aa)), aa, rtol=1e-5, atol=1e-15)


def test_6d_round_trip_and_gram_schmidt() -> None:
    aa = sample_axis_angles(seed=1)
    same_rotation(rot.sixd_to_axis_angle(rot.axis_angle_to_6d(aa)), aa)
    d6 = rot.axis_angle_to_6d(aa)
    noisy = d6 * 3.0 + np.random.default_rng(0).normal(scale=0.01, size=d6.shape)  # not orthonormal
    m = rot.sixd_to_matrix(noisy)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-9)
    np.testing.assert_allclose(m[:, 0, :], d6[:, :3], atol=0.02)


def test_6d_is_the_first_two_rows_as_pytorch3d_stores_it() -> None:
    m = Rotation.from_rotvec(sample_axis_angles(seed=4)).as_matrix()
    np.testing.assert_allclose(rot.matrix_to_6d(m), m[:, :2, :].reshape(-1, 6), atol=0)
    np.testing.assert_allclose(rot.sixd_to_matrix(m[:, :2, :].reshape(-1, 6)), m, atol=1e-12)


@pytest.mark.parametrize("order", ORDERS)
def test_euler_round_trips_and_matches_scipy(order: str) -> None:
    aa = sample_axis_angles(seed=2)
    eul = rot.axis_angle_to_euler(aa, order)
    same_rotation(rot.euler_to_axis_angle(eul, order), aa, tol=1e-6)
    assert np.all(np.abs(eul[:, 1]) <= np.pi / 2 + 1e-9)
    # Intrinsic: "ZXY" is Rz @ Rx @ Ry, which scipy spells in upper case.
    angles = np.random.default_rng(3).uniform(-np.pi, np.pi, size=(50, 3)) * [1, 0.45, 1]
    np.testing.assert_allclose(
        rot.euler_to_matrix(angles, order), Rotation.from_euler(order, angles).as_matrix(), atol=1e-12
    )
    np.testing.assert_allclose(rot.matrix_to_euler(rot.euler_to_matrix(angles, order), order), angles, atol=1e-9)


@pytest.mark.parametrize("order", ORDERS)
def test_euler_gimbal_lock(order: str) -> None:
    angles = np.array([[0.3, np.pi / 2, -0.2], [0.1, -np.pi / 2, 0.7]])
    m = rot.euler_to_matrix(angles, order)
    np.testing.assert_allclose(rot.euler_to_matrix(rot.matrix_to_euler(m, order), order), m, atol=1e-9)


def test_bad_euler_order() -> None:
    with pytest.raises(ValueError, match="permutation"):
        rot.euler_to_matrix(np.zeros(3), "XXY")


def test_slerp_and_multiply() -> None:
    a = rot.axis_angle_to_quat(np.array([0.0, 0.0, 0.2]))
    b = rot.axis_angle_to_quat(np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(rot.quat_to_axis_angle(rot.quat_slerp(a, b, 0.25)), [0, 0, 0.4], atol=1e-12)
    np.testing.assert_allclose(
        rot.quat_slerp(a, -b, 1.0) * np.sign(rot.quat_slerp(a, -b, 1.0)[0]), b, atol=1e-12
    )  # short way
    ab = rot.quat_multiply(a, b)
    np.testing.assert_allclose(rot.quat_to_matrix(ab), rot.quat_to_matrix(a) @ rot.quat_to_matrix(b), atol=1e-12)


def test_skeleton_sanity() -> None:
    assert NUM_JOINTS == 55 == len(set(JOINT_NAMES)) == len(PARENTS)
    assert PARENTS[0] == -1 and all(0 <= p < j for j, p in enumerate(PARENTS) if j)
    assert JOINT_NAMES[15] == "head" and JOINT_NAMES[PARENTS[JOINT_NAMES.index("jaw")]] == "head"
    for j, name in enumerate(JOINT_NAMES):
        if name.startswith("left_"):
            m = JOINT_NAMES.index(name.replace("left_", "right_"))
            np.testing.assert_allclose(REST_POSITIONS[m], REST_POSITIONS[j] * [-1, 1, 1])
            assert REST_POSITIONS[j, 0] > 0  # the character's left is +X
            assert JOINT_NAMES[PARENTS[m]] == JOINT_NAMES[PARENTS[j]].replace("left_", "right_")
        elif not name.startswith("right_"):
            assert REST_POSITIONS[j, 0] == 0  # midline
    height = REST_POSITIONS[:, 1].max() - REST_POSITIONS[:, 1].min()
    assert 1.5 < height < 1.9 and np.all(np.linalg.norm(REST_OFFSETS[1:], axis=1) > 0)


def test_forward_kinematics() -> None:
    _, rest = forward_kinematics(np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)))
    np.testing.assert_allclose(rest, REST_POSITIONS, atol=1e-12)
    local = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
    elbow = JOINT_NAMES.index("left_elbow")
    local[elbow] = Rotation.from_euler("z", np.pi / 2).as_matrix()
    glob, pos = forward_kinematics(local, root_translation=np.array([0.0, 0.1, 0.0]))
    wrist = JOINT_NAMES.index("left_wrist")
    bone = REST_POSITIONS[wrist] - REST_POSITIONS[elbow]
    expected = REST_POSITIONS[elbow] + [0, 0.1, 0] + Rotation.from_euler("z", np.pi / 2).apply(bone)
    np.testing.assert_allclose(pos[wrist], expected, atol=1e-12)
    np.testing.assert_allclose(glob[JOINT_NAMES.index("left_index3")], local[elbow], atol=1e-12)


def random_clip(n: int = 20) -> MotionClip:
    rng = np.random.default_rng(5)
    clip = MotionClip.neutral(n, fps=30)
    clip.pose[:] = rng.normal(scale=0.3, size=clip.pose.shape)
    clip.translation[:] = rng.normal(scale=0.1, size=(n, 3))
    clip.face[:] = rng.uniform(size=clip.face.shape)
    clip.vad[:] = rng.uniform(size=(n, 2))
    clip.state[:] = rng.integers(0, 4, n)
    clip.metadata.update({"generator": "test", "seed": 5})
    return clip


def test_npz_round_trip(tmp_path: Path) -> None:
    clip = random_clip()
    back = load_clip(save_clip(clip, tmp_path / "c.npz"))
    for key in ("pose", "translation", "face", "vad", "state"):
        np.testing.assert_array_equal(getattr(back, key), getattr(clip, key))
    assert back.fps == 30 and back.metadata == clip.metadata
    assert [p.name for p in tmp_path.iterdir()] == ["c.npz"]


def rewrite(src: Path, dst: Path, **changes) -> Path:
    """Copy an npz, replacing (value) or dropping (None) arrays."""
    with np.load(src, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    np.savez(dst, **arrays)
    return dst


@pytest.mark.parametrize(
    "changes, problem",
    [
        ({"format_version": np.array(FORMAT_VERSION + 1)}, "version"),
        ({"face": None}, "missing arrays: face"),
        ({"format": None}, "format"),
        ({"joint_names": np.array(["a"] * 55)}, "joint names"),
        ({"fps": np.array(0.0)}, "fps"),
    ],
)
def test_npz_validation(tmp_path: Path, changes: dict, problem: str) -> None:
    good = save_clip(random_clip(), tmp_path / "good.npz")
    bad = rewrite(good, tmp_path / "bad.npz", **changes)
    with pytest.raises(InputFileError, match=problem) as err:
        load_clip(bad)
    assert str(bad) in str(err.value)


def test_npz_rejects_nan_and_face_out_of_range(tmp_path: Path) -> None:
    clip = random_clip()
    good = save_clip(clip, tmp_path / "good.npz")
    pose = clip.pose.copy()
    pose[3, 4, 1] = np.nan
    with pytest.raises(InputFileError, match="'pose' holds NaN"):
        load_clip(rewrite(good, tmp_path / "nan.npz", pose=pose))
    face = clip.face.copy()
    face[0, 0] = 1.5
    with pytest.raises(InputFileError, match="outside"):
        load_clip(rewrite(good, tmp_path / "face.npz", face=face))
    with pytest.raises(InputFileError, match="shape"):
        load_clip(rewrite(good, tmp_path / "short.npz", vad=clip.vad[:-1]))


def test_npz_not_a_zip_or_pickled(tmp_path: Path) -> None:
    text = tmp_path / "t.npz"
    text.write_text("not a zip")
    with pytest.raises(InputFileError, match="not a convodrive motion"):
        load_clip(text)
    pickled = tmp_path / "p.npz"
    np.savez(pickled, format=np.array({"evil": 1}, dtype=object))
    with pytest.raises(InputFileError):
        load_clip(pickled)
    with pytest.raises(InputFileError, match="no such file"):
        load_clip(tmp_path / "absent.npz")


def test_global_rotation_of_one_joint_equals_full_forward_kinematics() -> None:
    from convodrive.motion.rotations import axis_angle_to_matrix
    from convodrive.motion.skeleton import JOINT_INDEX, forward_kinematics, global_rotation

    rng = np.random.default_rng(3)
    local = axis_angle_to_matrix(rng.normal(scale=0.4, size=(7, 55, 3)))
    glob, _ = forward_kinematics(local)
    for name in ("head", "left_wrist", "right_thumb3", "pelvis"):
        np.testing.assert_allclose(global_rotation(local, JOINT_INDEX[name]), glob[:, JOINT_INDEX[name]], atol=1e-12)
