"""BVH export checked by an independent parser (PyPI ``bvh``) and scipy's Euler angles; import of ours and others'."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from convodrive.motion.bvh import write_bvh
from convodrive.motion.bvh_read import canonical_joint_name, read_bvh
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES, PARENTS, REST_OFFSETS, REST_POSITIONS
from convodrive.plumbing.errors import InputFileError


def random_clip(num_frames: int = 24, seed: int = 0) -> MotionClip:
    rng = np.random.default_rng(seed)
    clip = MotionClip.neutral(num_frames)
    axes = rng.normal(size=(num_frames, 55, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    clip.pose[:] = axes * rng.uniform(0, np.pi, size=(num_frames, 55, 1))
    clip.pose[0] = 0.0  # rest frame
    clip.pose[1, :, :] = [np.pi / 2, 0, 0]  # Euler ZXY gimbal lock on every joint
    clip.translation[:] = rng.normal(scale=0.3, size=(num_frames, 3))
    return clip


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle of a^T b for stacks of matrices."""
    return Rotation.from_matrix(np.swapaxes(a, -1, -2) @ b).magnitude()


@pytest.mark.bvh_reader
def test_export_read_by_third_party_parser(tmp_path: Path) -> None:
    import bvh

    clip = random_clip()
    path = write_bvh(clip, tmp_path / "clip.bvh")
    parsed = bvh.Bvh(path.read_text())
    assert parsed.get_joints_names() == [n for n in parsed.get_joints_names() if n in JOINT_NAMES]
    assert sorted(parsed.get_joints_names()) == sorted(JOINT_NAMES)
    assert parsed.nframes == clip.num_frames
    assert parsed.frame_time == pytest.approx(1 / 30, abs=1e-6)
    for j, name in enumerate(JOINT_NAMES):
        parent = parsed.joint_parent(name)
        assert (parent.name if parent else None) == (JOINT_NAMES[PARENTS[j]] if PARENTS[j] >= 0 else None)
        np.testing.assert_allclose(parsed.joint_offset(name), REST_OFFSETS[j] * 100, atol=1e-5)
        channels = [c for c in parsed.joint_channels(name) if c.endswith("rotation")]
        degrees = np.array(parsed.frames_joint_channels(name, channels))
        # Uppercase axes in scipy are intrinsic rotations, as BVH channel lists compose.
        theirs = Rotation.from_euler("".join(c[0] for c in channels), degrees, degrees=True).as_matrix()
        ours = Rotation.from_rotvec(clip.pose[:, j].astype(np.float64)).as_matrix()
        assert angle_between(theirs, ours).max() < 1e-4, name
    root = np.array(parsed.frames_joint_channels("pelvis", ["Xposition", "Yposition", "Zposition"]))
    np.testing.assert_allclose(root / 100, REST_POSITIONS[0] + clip.translation, atol=1e-6)


def test_round_trip(tmp_path: Path) -> None:
    clip = random_clip(num_frames=1030, seed=3)  # past the writer's 1024-frame block
    back = read_bvh(write_bvh(clip, tmp_path / "clip.bvh"))
    assert back.num_frames == clip.num_frames and back.fps == 30
    err = angle_between(
        Rotation.from_rotvec(back.pose.reshape(-1, 3)).as_matrix(),
        Rotation.from_rotvec(clip.pose.reshape(-1, 3)).as_matrix(),
    )
    assert err.max() < 1e-4
    np.testing.assert_allclose(back.translation, clip.translation, atol=1e-5)
    assert len(back.metadata["mapped_joints"]) == 55


THIRD_PARTY = """HIERARCHY
ROOT mixamorig:Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
  JOINT LowerBack
  {
    OFFSET 0 0.1 0
    CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
    JOINT mixamorig:Spine
    {
      OFFSET 0 0.1 0
      CHANNELS 3 Yrotation Xrotation Zrotation
      End Site
      {
        OFFSET 0 0.1 0
      }
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 0.1 0 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    End Site
    {
      OFFSET 0 -0.4 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.016667
0.0 1.0 0.5  10 20 30   1 2 3 40 50 60   5 -15 25   -30 12 70
0.1 1.0 0.5  0 0 0      0 0 0 0 0 0      0 0 0      0 0 0
"""


def test_third_party_names_orders_and_units(tmp_path: Path) -> None:
    path = tmp_path / "other.bvh"
    path.write_text(THIRD_PARTY)
    clip = read_bvh(path)
    assert clip.fps == 60 and clip.num_frames == 2
    expected = {
        "pelvis": ("XYZ", [10, 20, 30]),
        "spine1": ("YXZ", [5, -15, 25]),
        "left_hip": ("XZY", [-30, 12, 70]),
    }
    for name, (order, deg) in expected.items():
        want = Rotation.from_euler(order, deg, degrees=True).as_matrix()
        got = Rotation.from_rotvec(clip.pose[0, JOINT_INDEX[name]]).as_matrix()
        assert angle_between(want, got) < 1e-4, name
    # Unmapped (LowerBack) and missing joints (everything else) stay at rest.
    mapped = {JOINT_INDEX[n] for n in expected}
    others = [j for j in range(55) if j not in mapped]
    assert np.all(clip.pose[:, others] == 0)
    # Metres (the skeleton is under 10 units across): positions are taken as they are.
    np.testing.assert_allclose(clip.translation[1], np.array([0.1, 1.0, 0.5]) - REST_POSITIONS[0], atol=1e-6)


def test_centimetre_files_are_scaled(tmp_path: Path) -> None:
    path = tmp_path / "cm.bvh"
    text = THIRD_PARTY.replace("OFFSET 0 0.1 0", "OFFSET 0 10 0").replace("OFFSET 0.1 0 0", "OFFSET 10 0 0")
    text = (
        text.replace("OFFSET 0 -0.4 0", "OFFSET 0 -40 0")
        .replace("0.0 1.0 0.5", "0 100 50")
        .replace("0.1 1.0 0.5", "10 100 50")
    )
    path.write_text(text)
    clip = read_bvh(path)
    np.testing.assert_allclose(clip.translation[1], np.array([0.1, 1.0, 0.5]) - REST_POSITIONS[0], atol=1e-6)


@pytest.mark.parametrize(
    "name, expected",
    [
        ("Hips", "pelvis"),
        ("mixamorig:LeftForeArm", "left_elbow"),
        ("RightHandPinky2", "right_pinky2"),
        ("LeftShoulder", "left_collar"),
        ("hand_r", "right_wrist"),
        ("Spine2", "spine3"),
        ("spine2", "spine2"),
        ("LeftToeBase", "left_foot"),
        ("LowerBack", None),
        ("Tail", None),
    ],
)
def test_name_aliases(name: str, expected: str | None) -> None:
    assert canonical_joint_name(name) == expected


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda t: "hello world\n", "line 1"),
        (lambda t: t.replace("Frames: 2", "Frames: 3"), "declares 3 frames"),
        (lambda t: t.replace("5 -15 25", "5 -15"), "line 33: frame 0 has 17 values"),
        (lambda t: t.replace("5 -15 25", "5 x 25"), "not a number"),
        (lambda t: t.replace("5 -15 25", "5 nan 25"), "NaN"),
        (lambda t: t.replace("CHANNELS 3 Yrotation", "CHANNELS 3 Wrotation"), "CHANNELS"),
        (lambda t: t.split("MOTION")[0], "no MOTION"),
        (lambda t: t.replace("  JOINT LeftUpLeg\n  {", "  JOINT LeftUpLeg\n"), "line"),
        (
            lambda t: (
                t.replace("LowerBack", "Tail")
                .replace("Hips", "Base")
                .replace("Spine", "Neck2")
                .replace("LeftUpLeg", "Fin")
            ),
            "no joint matches",
        ),
    ],
)
def test_malformed_bvh_is_an_input_file_error(tmp_path: Path, mutate, message: str) -> None:
    path = tmp_path / "bad.bvh"
    path.write_text(mutate(THIRD_PARTY))
    with pytest.raises(InputFileError) as err:
        read_bvh(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_binary_and_missing_files(tmp_path: Path) -> None:
    path = tmp_path / "noise.bvh"
    path.write_bytes(np.random.default_rng(0).bytes(2000))
    with pytest.raises(InputFileError, match="noise.bvh"):
        read_bvh(path)
    with pytest.raises(InputFileError, match="no such file"):
        read_bvh(tmp_path / "absent.bvh")
