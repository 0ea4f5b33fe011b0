"""Live Link Face formats: the app's CSV takes (export and import), which face rigs import, and
its UDP packets (``encode_packet``), which Unreal's Live Link plugin listens to.

One row per frame: ``Timecode`` (HH:MM:SS:FF.mmm, FF counting frames at the clip's rate and mmm
the sub-frame in thousandths), ``BlendShapeCount`` (61 = 52 blendshapes + 9 rotations), the 52
ARKit weights in [0, 1] with capitalised names, then head and eye rotations in radians.

The blendshape columns follow the app's published column order, which differs from ARKit's list
in two places (``JawRight`` before ``JawLeft``, ``MouthRight`` before ``MouthLeft``); readers match
columns by name, and so do we. Rotations use our skeleton's axes (Y up, facing +Z, the
character's left +X): yaw about Y, pitch about X, roll about Z, R = Ry(yaw) Rx(pitch) Rz(roll).
The head's is its global orientation (pelvis through neck to head, by forward kinematics); each
eye's is relative to the head, as an eye-tracking camera sees it.

``read_livelink_csv`` imports such a take (ours or the app's): face channels by column name, the
head's rotation onto the head joint (the spine and neck stay at rest, so its global rotation is the
file's), the eyes' onto the eye joints, and the jaw joint from ``jawOpen``. The body, root and voice
activity are not in the format and stay at rest. The frame rate is read from the timecodes: the
common rate at which consecutive rows are one frame apart (30 when a take is too short to tell).
"""

from __future__ import annotations

import csv
import os
import re
import struct
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from convodrive import FPS
from convodrive.motion import rotations
from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX, JAW_OPEN_RAD, NUM_BLENDSHAPES
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX, NUM_JOINTS, global_rotation
from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.errors import InputFileError

BLENDSHAPE_COUNT = 61
_SWAPS = {"jawLeft": "jawRight", "jawRight": "jawLeft", "mouthLeft": "mouthRight", "mouthRight": "mouthLeft"}
LIVELINK_BLENDSHAPES: tuple[str, ...] = tuple(_SWAPS.get(n, n) for n in ARKIT_NAMES)
"""The 52 ARKit names in the app's column order (still camelCase)."""
ROTATION_COLUMNS: tuple[str, ...] = (
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
)
HEADER: tuple[str, ...] = (
    ("Timecode", "BlendShapeCount") + tuple(n[0].upper() + n[1:] for n in LIVELINK_BLENDSHAPES) + ROTATION_COLUMNS
)
_YAW_PITCH_ROLL = "YXZ"
_BLOCK = 1024


def timecode(seconds: float, fps: float) -> str:
    """``HH:MM:SS:FF.mmm`` for a time in seconds from the start of the take."""
    whole = int(np.floor(seconds + 1e-9))
    frames = (seconds - whole) * fps
    ff = int(np.floor(frames + 1e-6))
    mmm = min(999, int(round((frames - ff) * 1000)))
    return f"{whole // 3600:02d}:{whole // 60 % 60:02d}:{whole % 60:02d}:{ff:02d}.{mmm:03d}"


def head_eye_rotations(pose: np.ndarray) -> np.ndarray:
    """(T, 9) yaw, pitch, roll of the head (global) and of the left and right eyes (in the head),
    from local axis-angle poses (T, 55, 3)."""
    local = rotations.axis_angle_to_matrix(pose)
    mats = np.stack(
        [
            global_rotation(local, JOINT_INDEX["head"]),
            local[:, JOINT_INDEX["left_eye_smplhf"]],
            local[:, JOINT_INDEX["right_eye_smplhf"]],
        ],
        axis=1,
    )
    return rotations.matrix_to_euler(mats, _YAW_PITCH_ROLL).reshape(len(pose), 9)


def write_livelink_csv(clip: MotionClip, path: str | os.PathLike[str]) -> Path:
    """Write ``clip`` as a Live Link Face CSV (atomically)."""
    blocks = (
        (clip.face[start : start + _BLOCK], clip.pose[start : start + _BLOCK])
        for start in range(0, clip.num_frames, _BLOCK)
    )
    return write_livelink_blocks(path, clip.fps, blocks)


def write_livelink_blocks(
    path: str | os.PathLike[str], fps: float, blocks: Iterable[tuple[np.ndarray, np.ndarray]]
) -> Path:
    """Write frames given as (face (n, 52), pose (n, 55, 3)) blocks of consecutive frames, atomically:
    hours of motion in bounded memory."""
    path = Path(path)
    columns = [BLENDSHAPE_INDEX[n] for n in LIVELINK_BLENDSHAPES]
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="ascii", newline="") as fh:
            fh.write(",".join(HEADER) + "\r\n")
            index = 0
            row_format = f"%s,{BLENDSHAPE_COUNT}," + ",".join(["%.6f"] * (len(columns) + 9)) + "\r\n"
            for face, pose in blocks:
                angles = head_eye_rotations(pose)
                for row in np.concatenate([face[:, columns], angles], axis=1).tolist():
                    fh.write(row_format % (timecode(index / fps, fps), *row))
                    index += 1
    return path


# ---------------------------------------------------------------- import

COMMON_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 90.0, 100.0, 120.0)
_TIMECODE = re.compile(r"(\d+):(\d{1,2}):(\d{1,2}):(\d+)(?:\.(\d+))?")
_MAX_GAP_SECONDS = 10.0
"""Missing rows are held from the previous one; a longer jump in the timecodes is refused."""


def read_livelink_csv(path: str | os.PathLike[str]) -> MotionClip:
    """Import a Live Link Face CSV take as a clip (see the module notes)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such file")
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except UnicodeDecodeError:
        raise InputFileError(path, "not a Live Link Face CSV (not text)") from None
    except (OSError, csv.Error) as exc:
        raise InputFileError(path, f"cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    if not rows or not rows[0] or rows[0][0].strip() != "Timecode":
        raise InputFileError(path, "line 1: not a Live Link Face CSV (expected a 'Timecode' column first)")
    columns = {name.strip().lower(): k for k, name in enumerate(rows[0])}
    face_cols = {n: columns.get(n.lower()) for n in ARKIT_NAMES}
    if all(c is None for c in face_cols.values()):
        raise InputFileError(path, "line 1: no ARKit blendshape column (e.g. JawOpen, EyeBlinkLeft)")
    rotation_cols = [columns.get(n.lower()) for n in ROTATION_COLUMNS]
    body = [(n, row) for n, row in enumerate(rows[1:], start=2) if any(cell.strip() for cell in row)]
    if not body:
        raise InputFileError(path, "holds no frames")
    times = np.empty((len(body), 3))  # whole seconds, frame number, sub-frame
    values = np.zeros((len(body), NUM_BLENDSHAPES + len(ROTATION_COLUMNS)))
    wanted = [(k, c) for k, c in enumerate(list(face_cols.values()) + rotation_cols) if c is not None]
    for i, (line, row) in enumerate(body):
        match = _TIMECODE.fullmatch(row[0].strip())
        if match is None:
            raise InputFileError(path, f"line {line}: timecode {row[0][:40]!r} is not HH:MM:SS:FF.mmm")
        hh, mm, ss, ff, sub = match.groups()
        times[i] = (int(hh) * 3600 + int(mm) * 60 + int(ss), int(ff), float(f"0.{sub}") if sub else 0.0)
        try:
            for k, c in wanted:
                values[i, k] = float(row[c])
        except (IndexError, ValueError):
            raise InputFileError(path, f"line {line}: a value is missing or not a number") from None
        if not np.all(np.isfinite(values[i])):
            raise InputFileError(path, f"line {line}: holds NaN or infinite values")
    fps = _timecode_rate(times)
    index = _frame_indices(path, times, fps, [line for line, _ in body])
    num_frames = int(index[-1]) + 1
    # Each output frame takes the latest row at or before it: missing rows hold the previous one.
    source = np.searchsorted(index, np.arange(num_frames), side="right") - 1
    values = values[source]

    face = np.clip(values[:, :NUM_BLENDSHAPES], 0.0, 1.0)
    pose = np.zeros((num_frames, NUM_JOINTS, 3))
    angles = values[:, NUM_BLENDSHAPES:].reshape(num_frames, 3, 3)
    for k, joint in enumerate(("head", "left_eye_smplhf", "right_eye_smplhf")):
        pose[:, JOINT_INDEX[joint]] = rotations.euler_to_axis_angle(angles[:, k], _YAW_PITCH_ROLL)
    pose[:, JOINT_INDEX["jaw"], 0] = face[:, BLENDSHAPE_INDEX["jawOpen"]] * JAW_OPEN_RAD
    return MotionClip(
        pose=pose.astype(np.float32),
        translation=np.zeros((num_frames, 3), np.float32),
        face=face.astype(np.float32),
        vad=np.zeros((num_frames, 2), np.float32),
        state=np.zeros(num_frames, np.int8),
        fps=fps,
        metadata={
            "source": str(path),
            "format": "livelink",
            "missing_columns": [n for n, c in face_cols.items() if c is None]
            + [n for n, c in zip(ROTATION_COLUMNS, rotation_cols) if c is None],
        },
    )


def _timecode_rate(times: np.ndarray) -> float:
    """The common rate at which most consecutive rows are one frame apart (ties: 30, then the lowest)."""
    top = int(times[:, 1].max()) + 1
    candidates = [r for r in COMMON_RATES if r >= top] or [float(top)]

    def one_frame_steps(rate: float) -> float:
        steps = np.diff(times[:, 0] * rate + times[:, 1] + times[:, 2])
        return float(np.mean(np.abs(steps - 1.0) < 0.01)) if len(steps) else 1.0

    return max(candidates, key=lambda r: (one_frame_steps(r), r == FPS, -r))


def _frame_indices(path: Path, times: np.ndarray, fps: float, lines: list[int]) -> np.ndarray:
    frames = times[:, 0] * fps + times[:, 1] + times[:, 2]
    index = np.round(frames - frames[0]).astype(np.int64)
    steps = np.diff(index)
    if len(steps) and steps.min() < 0:
        bad = int(np.argmin(steps)) + 1
        raise InputFileError(path, f"line {lines[bad]}: timecode goes backwards")
    if len(steps) and steps.max() > _MAX_GAP_SECONDS * fps:
        bad = int(np.argmax(steps)) + 1
        gap = steps.max() / fps
        raise InputFileError(
            path, f"line {lines[bad]}: timecode jumps {gap:.1f} s ahead (a gap of more than {_MAX_GAP_SECONDS:g} s)"
        )
    return index


# ---------------------------------------------------------------- UDP packets

UDP_PORT = 11111
"""Where the app sends, and Unreal's Live Link Face source listens, by default."""
PACKET_VERSION = 6
_ARKIT_ORDER = [BLENDSHAPE_INDEX[n] for n in ARKIT_NAMES]


def encode_packet(
    device_id: str, subject: str, frame: int, face: np.ndarray, rotations: np.ndarray, fps: int = 30
) -> bytes:
    """One Live Link Face UDP datagram, big-endian as the app sends it: the packet version (a byte),
    the device id and the subject name (each an int32 length and UTF-8), the frame time (frame
    number int32, sub-frame float32, rate numerator and denominator int32), the value count (a
    byte, 61), then 61 float32: the 52 blendshapes in ARKit's order (Unreal's ``EARFaceBlendShape``;
    the CSV's column order differs) and head yaw, pitch, roll and the eyes' (``head_eye_rotations``).
    """
    device = device_id.encode("utf-8")
    name = subject.encode("utf-8")
    values = np.concatenate([np.asarray(face, np.float32)[_ARKIT_ORDER], np.asarray(rotations, np.float32)])
    return (
        struct.pack(">Bi", PACKET_VERSION, len(device))
        + device
        + struct.pack(">i", len(name))
        + name
        + struct.pack(">ifiiB", int(frame), 0.0, int(fps), 1, BLENDSHAPE_COUNT)
        + values.astype(">f4").tobytes()
    )
