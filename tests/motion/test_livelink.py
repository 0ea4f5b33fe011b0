"""Live Link Face CSV export: header as the app writes it, one row per frame, head and eye angles."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX
from convodrive.motion.clip import MotionClip
from convodrive.motion.livelink import timecode, write_livelink_csv
from convodrive.motion.skeleton import JOINT_INDEX

ROTATIONS = [
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
]


def rotvec(axis: str, angle: float) -> np.ndarray:
    return Rotation.from_euler(axis, angle).as_rotvec()


def read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def test_header_rows_and_face(tmp_path: Path) -> None:
    clip = MotionClip.neutral(45)
    clip.face[:, BLENDSHAPE_INDEX["jawOpen"]] = np.linspace(0, 1, 45)
    clip.face[:, BLENDSHAPE_INDEX["jawLeft"]] = 0.25
    clip.face[:, BLENDSHAPE_INDEX["mouthRight"]] = 0.75
    header, rows = read_rows(write_livelink_csv(clip, tmp_path / "face.csv"))
    assert header[:2] == ["Timecode", "BlendShapeCount"]
    assert header[-9:] == ROTATIONS
    assert header[2:5] == ["EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft"] and header[-10] == "TongueOut"
    assert sorted(header[2:-9]) == sorted(n[0].upper() + n[1:] for n in ARKIT_NAMES)
    # The app's own column order puts JawRight before JawLeft and MouthRight before MouthLeft.
    assert header.index("JawRight") < header.index("JawLeft") and header.index("MouthRight") < header.index("MouthLeft")
    assert len(rows) == 45
    assert {r["BlendShapeCount"] for r in rows} == {"61"}
    assert rows[0]["Timecode"] == "00:00:00:00.000" and rows[31]["Timecode"] == "00:00:01:01.000"
    assert float(rows[44]["JawOpen"]) == pytest.approx(1.0) and float(rows[22]["JawOpen"]) == pytest.approx(
        0.5, abs=1e-6
    )
    assert float(rows[0]["JawLeft"]) == pytest.approx(0.25) and float(rows[0]["JawRight"]) == 0.0
    assert float(rows[0]["MouthRight"]) == pytest.approx(0.75) and float(rows[0]["MouthLeft"]) == 0.0


def test_head_is_global_and_eyes_are_in_the_head(tmp_path: Path) -> None:
    clip = MotionClip.neutral(3)
    # Yaw split over spine3 and neck, pitch at the head: the head's global yaw is the sum.
    clip.pose[1, JOINT_INDEX["spine3"]] = rotvec("y", 0.2)
    clip.pose[1, JOINT_INDEX["neck"]] = rotvec("y", 0.15)
    clip.pose[1, JOINT_INDEX["head"]] = rotvec("x", -0.1)
    clip.pose[2, JOINT_INDEX["head"]] = Rotation.from_euler("YXZ", [0.4, 0.3, -0.2]).as_rotvec()
    clip.pose[2, JOINT_INDEX["left_eye_smplhf"]] = rotvec("y", 0.25)
    clip.pose[2, JOINT_INDEX["right_eye_smplhf"]] = rotvec("x", -0.12)
    _, rows = read_rows(write_livelink_csv(clip, tmp_path / "face.csv"))
    got = np.array([[float(r[c]) for c in ROTATIONS] for r in rows])
    np.testing.assert_allclose(got[0], 0.0, atol=1e-6)
    np.testing.assert_allclose(got[1, :3], [0.35, -0.1, 0.0], atol=1e-5)
    np.testing.assert_allclose(got[2], [0.4, 0.3, -0.2, 0.25, 0, 0, 0, -0.12, 0], atol=1e-5)


def test_long_clip_rows_follow_their_frames(tmp_path: Path) -> None:
    clip = MotionClip.neutral(1100)  # past the writer's 1024-frame block
    yaw = np.linspace(-0.5, 0.5, 1100)
    clip.pose[:, JOINT_INDEX["head"], 1] = yaw
    _, rows = read_rows(write_livelink_csv(clip, tmp_path / "face.csv"))
    assert len(rows) == 1100 and rows[1099]["Timecode"] == "00:00:36:19.000"
    np.testing.assert_allclose([float(r["HeadYaw"]) for r in rows], yaw, atol=1e-6)


@pytest.mark.parametrize(
    "seconds, expected",
    [(0, "00:00:00:00.000"), (3725 + 29 / 30, "01:02:05:29.000"), (1.0 + 1 / 60, "00:00:01:00.500")],
)
def test_timecode(seconds: float, expected: str) -> None:
    assert timecode(seconds, 30) == expected
