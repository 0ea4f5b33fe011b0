"""The one motion loader: a clip from any file convodrive reads, told apart by its suffix.

``.npz`` (convodrive's own, validated), ``.bvh`` (any skeleton, mapped by joint name) and ``.csv``
(a Live Link Face take). Every problem is an ``InputFileError`` naming the file; a file with no
frames is one too. The clip keeps its own rate: ``convodrive.motion.resample`` reads it at 30 fps.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX, NUM_JOINTS
from convodrive.plumbing.errors import InputFileError


def _read_npz(path: Path) -> MotionClip:
    from convodrive.motion.npz import load_clip

    return load_clip(path)


def _read_bvh(path: Path) -> MotionClip:
    from convodrive.motion.bvh_read import read_bvh

    return read_bvh(path)


def _read_csv(path: Path) -> MotionClip:
    from convodrive.motion.livelink import read_livelink_csv

    return read_livelink_csv(path)


READERS: dict[str, Callable[[Path], MotionClip]] = {".npz": _read_npz, ".bvh": _read_bvh, ".csv": _read_csv}
FORMATS = "convodrive .npz, BVH or Live Link Face .csv"
_HEAD_JOINTS = {JOINT_INDEX[n] for n in ("head", "jaw", "left_eye_smplhf", "right_eye_smplhf")}


def load_motion(path: str | os.PathLike[str]) -> MotionClip:
    """A clip from ``path``; the format follows the suffix."""
    path = Path(path)
    reader = READERS.get(path.suffix.lower())
    if reader is None:
        raise InputFileError(path, f"unsupported motion format '{path.suffix or '(none)'}' (expected {FORMATS})")
    if path.is_dir():
        raise InputFileError(path, "is a folder, not a motion file")
    if not path.is_file():
        raise InputFileError(path, "no such file")
    if not os.access(path, os.R_OK):
        raise InputFileError(path, "cannot read (permission denied)")
    clip = reader(path)
    if clip.num_frames == 0:
        raise InputFileError(path, "holds no frames")
    return clip


def absent_parts(clip: MotionClip) -> list[str]:
    """The parts of the canonical motion a clip leaves still from start to end, in words: a BVH has
    no face channels, a Live Link take no body. Whoever plays a clip warns about these."""
    parts = []
    if not np.any(clip.face):
        parts.append("face (every blendshape channel is 0)")
    body = [j for j in range(NUM_JOINTS) if j not in _HEAD_JOINTS]
    if not np.any(clip.pose[:, body]) and not np.any(clip.translation):
        parts.append("body (every joint below the head is at rest)")
    return parts
