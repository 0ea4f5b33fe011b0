"""The clip file: one versioned ``.npz``, validated on load.

Layout (format version 1): arrays ``pose`` (T, 55, 3), ``translation`` (T, 3), ``face`` (T, 52),
``vad`` (T, 2), ``state`` (T,), the name lists ``joint_names`` and ``blendshape_names`` (so that a
reader can check, or remap, rather than trust positions), scalars ``fps`` and ``format_version``,
and ``metadata`` as a JSON string. No pickles: files load with ``allow_pickle=False``.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.motion.channels import ARKIT_NAMES, NUM_BLENDSHAPES
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_NAMES, NUM_JOINTS
from convodrive.plumbing.errors import InputFileError
from convodrive.plumbing.npzfile import Blocks, write_npz

FORMAT_VERSION = 1
_FORMAT_TAG = "convodrive.motion"
CLIP_FIELDS: dict[str, tuple[tuple[int, ...], np.dtype]] = {
    "pose": ((NUM_JOINTS, 3), np.dtype(np.float32)),
    "translation": ((3,), np.dtype(np.float32)),
    "face": ((NUM_BLENDSHAPES,), np.dtype(np.float32)),
    "vad": ((2,), np.dtype(np.float32)),
    "state": ((), np.dtype(np.int8)),
}
"""The per-frame arrays of a clip file: row shape and dtype."""


def save_clip(clip: MotionClip, path: str | os.PathLike[str]) -> Path:
    return write_clip_arrays(
        path,
        {
            "pose": clip.pose.astype(np.float32),
            "translation": clip.translation.astype(np.float32),
            "face": clip.face.astype(np.float32),
            "vad": clip.vad.astype(np.float32),
            "state": clip.state.astype(np.int8),
        },
        clip.fps,
        clip.metadata,
    )


def write_clip_arrays(
    path: str | os.PathLike[str], arrays: dict[str, np.ndarray | Blocks], fps: float, metadata: dict[str, Any]
) -> Path:
    """Write a clip file from its five arrays, in memory or streamed in blocks (``CLIP_FIELDS``), atomically."""
    return write_npz(
        path,
        {
            "format": np.array(_FORMAT_TAG),
            "format_version": np.array(FORMAT_VERSION),
            "fps": np.array(float(fps)),
            **{name: arrays[name] for name in CLIP_FIELDS},
            "joint_names": np.array(JOINT_NAMES),
            "blendshape_names": np.array(ARKIT_NAMES),
            "metadata": np.array(json.dumps(metadata, default=str)),
        },
    )


def load_clip(path: str | os.PathLike[str]) -> MotionClip:
    """Load and validate a clip; every problem is an ``InputFileError`` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such file")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise InputFileError(path, f"not a convodrive motion .npz ({exc.__class__.__name__})") from None
    if str(arrays.get("format", "")) != _FORMAT_TAG:
        raise InputFileError(path, "not a convodrive motion .npz (no 'format' tag)")
    version = int(arrays["format_version"]) if "format_version" in arrays else -1
    if version != FORMAT_VERSION:
        raise InputFileError(
            path, f"motion format version {version} is not supported (this convodrive reads {FORMAT_VERSION})"
        )
    missing = [
        k
        for k in ("pose", "translation", "face", "vad", "state", "fps", "joint_names", "blendshape_names")
        if k not in arrays
    ]
    if missing:
        raise InputFileError(path, f"missing arrays: {', '.join(missing)}")
    if tuple(str(n) for n in arrays["joint_names"]) != JOINT_NAMES:
        raise InputFileError(path, "joint names differ from the canonical 55-joint skeleton")
    if tuple(str(n) for n in arrays["blendshape_names"]) != ARKIT_NAMES:
        raise InputFileError(path, "blendshape names differ from the 52 ARKit channels")
    for key in ("pose", "translation", "face", "vad"):
        if not np.all(np.isfinite(arrays[key])):
            raise InputFileError(path, f"'{key}' holds NaN or infinite values")
    face = arrays["face"]
    if face.size and (face.min() < -1e-4 or face.max() > 1 + 1e-4):
        raise InputFileError(path, "'face' blendshape weights fall outside [0, 1]")
    fps = float(arrays["fps"])
    if not fps > 0:
        raise InputFileError(path, f"fps must be positive, got {fps}")
    try:
        metadata = json.loads(str(arrays["metadata"])) if "metadata" in arrays else {}
        return MotionClip(
            pose=arrays["pose"].astype(np.float32),
            translation=arrays["translation"].astype(np.float32),
            face=np.clip(face, 0.0, 1.0).astype(np.float32),
            vad=arrays["vad"].astype(np.float32),
            state=arrays["state"].astype(np.int8),
            fps=fps,
            metadata=metadata,
        )
    except (ValueError, json.JSONDecodeError) as exc:
        raise InputFileError(path, str(exc)) from None
