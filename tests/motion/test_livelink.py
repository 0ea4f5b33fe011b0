"""Live Link Face CSV: header as the app writes it, one row per frame, head and eye angles; and read back."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX, JAW_OPEN_RAD
from convodrive.motion.clip import MotionClip
from convodrive.motion.livelink import HEADER, LIVELINK_BLENDSHAPES, read_livelink_csv, timecode, write_livelink_csv
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.plumbing.errors import InputFileError

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


def test_reading_back_gives_the_face_head_eyes_and_jaw(tmp_path: Path) -> None:
    clip = MotionClip.neutral(50)
    t = np.arange(50) / 30
    clip.face[:, BLENDSHAPE_INDEX["jawOpen"]] = 0.5 + 0.5 * np.sin(5 * t)
    clip.face[:, BLENDSHAPE_INDEX["mouthLeft"]] = 0.3
    clip.pose[:, JOINT_INDEX["head"]] = Rotation.from_euler(
        "YXZ", np.stack([0.3 * t, 0.1 * t, -0.05 * t], 1)
    ).as_rotvec()
    clip.pose[:, JOINT_INDEX["left_eye_smplhf"]] = rotvec("y", 0.2)
    back = read_livelink_csv(write_livelink_csv(clip, tmp_path / "face.csv"))
    assert back.num_frames == 50 and back.fps == 30
    np.testing.assert_allclose(back.face, clip.face, atol=1e-6)
    for joint in ("head", "left_eye_smplhf", "right_eye_smplhf"):
        np.testing.assert_allclose(back.pose[:, JOINT_INDEX[joint]], clip.pose[:, JOINT_INDEX[joint]], atol=1e-5)
    # The jaw joint follows jawOpen, as every generator writes it.
    np.testing.assert_allclose(
        back.pose[:, JOINT_INDEX["jaw"], 0], clip.face[:, BLENDSHAPE_INDEX["jawOpen"]] * JAW_OPEN_RAD, atol=1e-6
    )
    assert not back.translation.any() and not back.vad.any()


@pytest.mark.parametrize("fps", [24, 25, 30, 50, 60])
def test_the_rate_comes_from_the_timecodes(tmp_path: Path, fps: int) -> None:
    clip = MotionClip.neutral(int(2.5 * fps), fps=fps)
    clip.face[:, 0] = np.arange(clip.num_frames) / clip.num_frames
    back = read_livelink_csv(write_livelink_csv(clip, tmp_path / "face.csv"))
    assert back.fps == fps and back.num_frames == clip.num_frames
    np.testing.assert_allclose(back.face[:, 0], clip.face[:, 0], atol=1e-6)


def _write_rows(path: Path, timecodes: list[str], jaw: list[float]) -> Path:
    lines = [",".join(HEADER)]
    for tc, j in zip(timecodes, jaw):
        values = [0.0] * 61
        values[LIVELINK_BLENDSHAPES.index("jawOpen")] = j
        lines.append(f"{tc},61," + ",".join(str(v) for v in values))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_missing_rows_hold_the_previous_one(tmp_path: Path) -> None:
    # The app drops frames now and then: rows 3 and 4 (of 30 fps) are missing.
    codes = [f"00:00:05:{f:02d}.000" for f in (0, 1, 2, 5, 6)] + [f"00:00:06:{f:02d}.000" for f in range(30)]
    back = read_livelink_csv(_write_rows(tmp_path / "t.csv", codes, [0.1, 0.2, 0.3, 0.6, 0.7] + [0.5] * 30))
    assert back.fps == 30 and back.num_frames == 60
    np.testing.assert_allclose(back.face[:7, BLENDSHAPE_INDEX["jawOpen"]], [0.1, 0.2, 0.3, 0.3, 0.3, 0.6, 0.7])


@pytest.mark.parametrize(
    "codes, needle",
    [
        (["00:00:01:05.000", "00:00:01:04.000"], "line 3: timecode goes backwards"),
        (["00:00:01:05.000", "00:05:01:06.000"], "line 3: timecode jumps"),
        (["00:00:01:05.000", "soon"], "line 3: timecode 'soon' is not HH:MM:SS:FF.mmm"),
    ],
)
def test_bad_timecodes_are_one_line(tmp_path: Path, codes: list[str], needle: str) -> None:
    path = _write_rows(tmp_path / "t.csv", codes, [0.0] * len(codes))
    with pytest.raises(InputFileError, match=needle):
        read_livelink_csv(path)


def test_bad_values_are_one_line(tmp_path: Path) -> None:
    path = _write_rows(tmp_path / "t.csv", ["00:00:00:00.000"], [0.0])
    path.write_text(path.read_text().replace(",0.0", ",nan", 1))
    with pytest.raises(InputFileError, match="line 2: holds NaN"):
        read_livelink_csv(path)
    path.write_text(path.read_text().replace(",nan", ",x", 1))
    with pytest.raises(InputFileError, match="line 2: a value is missing or not a number"):
        read_livelink_csv(path)
