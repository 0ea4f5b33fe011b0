"""Live Link Face CSV export: the take format of Epic's Live Link Face app, which face rigs import.

One row per frame: ``Timecode`` (HH:MM:SS:FF.mmm, FF counting frames at the clip's rate and mmm
the sub-frame in thousandths), ``BlendShapeCount`` (61 = 52 blendshapes + 9 rotations), the 52
ARKit weights in [0, 1] with capitalised names, then head and eye rotations in radians.

The blendshape columns follow the app's published column order, which differs from ARKit's list
in two places (``JawRight`` before ``JawLeft``, ``MouthRight`` before ``MouthLeft``); readers match
columns by name, and so do we. Rotations use our skeleton's axes (Y up, facing +Z, the
character's left +X): yaw about Y, pitch about X, roll about Z, R = Ry(yaw) Rx(pitch) Rz(roll).
The head's is its global orientation (pelvis through neck to head, by forward kinematics); each
eye's is relative to the head, as an eye-tracking camera sees it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from convodrive.motion import rotations
from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX, global_rotation
from convodrive.plumbing.atomic import atomic_path

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
    path = Path(path)
    face = clip.face[:, [BLENDSHAPE_INDEX[n] for n in LIVELINK_BLENDSHAPES]]
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="ascii", newline="") as fh:
            fh.write(",".join(HEADER) + "\r\n")
            for start in range(0, clip.num_frames, _BLOCK):  # in blocks: hours of motion in bounded memory
                angles = head_eye_rotations(clip.pose[start : start + _BLOCK])
                for i, row in enumerate(np.concatenate([face[start : start + _BLOCK], angles], axis=1), start):
                    values = ",".join(f"{v:.6f}" for v in row)
                    fh.write(f"{timecode(i / clip.fps, clip.fps)},{BLENDSHAPE_COUNT},{values}\r\n")
    return path
