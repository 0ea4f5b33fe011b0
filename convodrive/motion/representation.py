"""The learning representation: canonical motion <-> the feature vectors the models learn.

One module, NumPy only, shared by training (torch reads its arrays) and by the runtime (ONNX
outputs go back through ``decode``), so that a model sees the same numbers in both places.

Layout (``LAYOUT_VERSION`` 1): per frame a vector of ``FEATURE_DIM`` = 330 numbers, in named parts

    part   dims  content
    jaw       6  jaw rotation, 6D
    eyes     12  left, right eye rotation, 6D
    arkit    52  the 52 ARKit channels in [0, 1], ``ARKIT_NAMES`` order
    head     12  neck, head rotation, 6D
    upper    66  spine1..3, collars, shoulders, elbows, wrists, 6D
    hands   180  the 30 finger joints (left 15, right 15, skeleton order), 6D
    vad       2  voice activity of self and of the partner, in [0, 1]

so that the face (``GROUPS["face"]`` = jaw + eyes + arkit) and the body (``GROUPS["body"]`` =
head + upper + hands) are each one contiguous slice: the papers model them apart. Rotations are
*local* joint rotations, stored as the first two rows of the rotation matrix (PyTorch3D's
``matrix_to_rotation_6d``, the convention of ProbTalk and EMAGE; ``convodrive.motion.rotations``)
and read back through Gram-Schmidt, so any network output decodes to a valid rotation.

Not covered: the root (pelvis orientation and translation), hips, knees, ankles and feet. Seated
or standing conversation barely moves them and neither paper predicts them; ``decode`` takes them
from a ``base`` clip (or the rest pose).

Per-dimension normalisation statistics (``FeatureStats``) are computed from a corpus split
(``convodrive.corpus``) and stored as plain JSON beside a model. Channels a corpus lacks (ARKit
from FLAME data, hands without the MANO basis) are described by a per-dimension mask
(``feature_mask``): statistics skip them, and losses should too.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.motion import rotations
from convodrive.motion.channels import ARKIT_NAMES, NUM_BLENDSHAPES, VAD_NAMES, ConversationState
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS
from convodrive.plumbing.atomic import write_text_atomic
from convodrive.plumbing.errors import InputFileError

LAYOUT_VERSION = 1
SIXD = 6

_HAND_JOINTS = tuple(n for n in JOINT_NAMES if n.startswith(("left_", "right_")) and n[-1] in "123")
PART_JOINTS: dict[str, tuple[str, ...]] = {
    "jaw": ("jaw",),
    "eyes": ("left_eye_smplhf", "right_eye_smplhf"),
    "head": ("neck", "head"),
    "upper": (
        "spine1",
        "spine2",
        "spine3",
        "left_collar",
        "right_collar",
        "left_shoulder",
        "right_shoulder",
        "left_elbow",
        "right_elbow",
        "left_wrist",
        "right_wrist",
    ),
    "hands": _HAND_JOINTS,
}
"""The joints each rotation part covers, in the order their 6D blocks are stored."""

_PART_SIZES: tuple[tuple[str, int], ...] = (
    ("jaw", SIXD * len(PART_JOINTS["jaw"])),
    ("eyes", SIXD * len(PART_JOINTS["eyes"])),
    ("arkit", NUM_BLENDSHAPES),
    ("head", SIXD * len(PART_JOINTS["head"])),
    ("upper", SIXD * len(PART_JOINTS["upper"])),
    ("hands", SIXD * len(PART_JOINTS["hands"])),
    ("vad", len(VAD_NAMES)),
)


def _slices() -> dict[str, slice]:
    out, start = {}, 0
    for name, size in _PART_SIZES:
        out[name] = slice(start, start + size)
        start += size
    return out


PARTS: dict[str, slice] = _slices()
"""Each part's columns in the feature vector."""
GROUPS: dict[str, slice] = {
    "face": slice(PARTS["jaw"].start, PARTS["arkit"].stop),
    "body": slice(PARTS["head"].start, PARTS["hands"].stop),
    "vad": PARTS["vad"],
}
"""The face (jaw, eyes, ARKit), the body (head, upper body, hands) and voice activity."""
SPINE: slice = slice(
    PARTS["upper"].start, PARTS["upper"].start + SIXD * sum(j.startswith("spine") for j in PART_JOINTS["upper"])
)
"""spine1..3's 6D blocks, the first columns of the upper body: the torso's posture and breath."""
FEATURE_DIM: int = PARTS["vad"].stop
ROTATION_PARTS = ("jaw", "eyes", "head", "upper", "hands")
COVERED_JOINTS: tuple[str, ...] = tuple(j for p in ROTATION_PARTS for j in PART_JOINTS[p])
"""Joints the features carry; the others come from ``decode``'s base."""
_COVERED_INDEX = np.array([JOINT_INDEX[j] for j in COVERED_JOINTS])
_ROTATION_COLUMNS = np.concatenate([np.arange(PARTS[p].start, PARTS[p].stop) for p in ROTATION_PARTS])
STD_FLOOR = 1e-4
"""A dimension whose spread is below this (a constant channel) is scaled by 1, not blown up."""


def feature_names() -> list[str]:
    """One name per column, e.g. ``upper.left_elbow.3``, ``arkit.jawOpen``, ``vad.self``."""
    names: list[str] = []
    for part, _ in _PART_SIZES:
        if part in PART_JOINTS:
            names += [f"{part}.{j}.{k}" for j in PART_JOINTS[part] for k in range(SIXD)]
        elif part == "arkit":
            names += [f"arkit.{n}" for n in ARKIT_NAMES]
        else:
            names += [f"vad.{n}" for n in VAD_NAMES]
    return names


def layout() -> dict[str, Any]:
    """The layout as plain data, for a model folder's JSON: a runtime checks it before loading."""
    return {
        "version": LAYOUT_VERSION,
        "dim": FEATURE_DIM,
        "rotation": "6d: first two rows of the local rotation matrix (PyTorch3D matrix_to_rotation_6d)",
        "parts": {name: [s.start, s.stop] for name, s in PARTS.items()},
        "groups": {name: [s.start, s.stop] for name, s in GROUPS.items()},
        "joints": {name: list(joints) for name, joints in PART_JOINTS.items()},
    }


def encode(pose: np.ndarray, face: np.ndarray, vad: np.ndarray) -> np.ndarray:
    """Feature vectors (..., FEATURE_DIM) float32 from local axis-angle poses (..., 55, 3), ARKit
    weights (..., 52) and voice activity (..., 2); any leading axes (time, batch)."""
    pose = np.asarray(pose)
    lead = pose.shape[:-2]
    if pose.shape[-2:] != (NUM_JOINTS, 3):
        raise ValueError(f"pose must be (..., {NUM_JOINTS}, 3), got {pose.shape}")
    out = np.empty(lead + (FEATURE_DIM,), np.float32)
    sixd = rotations.axis_angle_to_6d(pose[..., _COVERED_INDEX, :])
    out[..., _ROTATION_COLUMNS] = sixd.reshape(lead + (-1,))
    out[..., PARTS["arkit"]] = face
    out[..., PARTS["vad"]] = vad
    return out


def encode_clip(clip: MotionClip) -> np.ndarray:
    """(T, FEATURE_DIM) features of a clip."""
    return encode(clip.pose, clip.face, clip.vad)


def decode_pose(features: np.ndarray, base_pose: np.ndarray | None = None) -> np.ndarray:
    """Local axis-angle poses (..., 55, 3) float32; uncovered joints from ``base_pose`` (or zero)."""
    features = np.asarray(features)
    lead = features.shape[:-1]
    pose = np.zeros(lead + (NUM_JOINTS, 3), np.float32) if base_pose is None else np.array(base_pose, np.float32)
    if pose.shape != lead + (NUM_JOINTS, 3):
        raise ValueError(f"base pose has shape {pose.shape}, expected {lead + (NUM_JOINTS, 3)}")
    sixd = features[..., _ROTATION_COLUMNS].reshape(lead + (len(COVERED_JOINTS), SIXD))
    pose[..., _COVERED_INDEX, :] = rotations.sixd_to_axis_angle(sixd)
    return pose


def decode(features: np.ndarray, base: MotionClip | None = None, fps: float | None = None) -> MotionClip:
    """A canonical clip from (T, FEATURE_DIM) features: rotations through Gram-Schmidt, face and
    voice activity clipped to [0, 1], the state from voice activity above 0.5. The root,
    translation and legs come from ``base`` (same length) or stay at rest."""
    features = np.asarray(features, np.float32)
    if features.ndim != 2 or features.shape[1] != FEATURE_DIM:
        raise ValueError(f"features must be (T, {FEATURE_DIM}), got {features.shape}")
    n = len(features)
    if base is not None and base.num_frames != n:
        raise ValueError(f"base clip has {base.num_frames} frames, features {n}")
    vad = np.clip(features[:, PARTS["vad"]], 0.0, 1.0)
    return MotionClip(
        pose=decode_pose(features, None if base is None else base.pose),
        translation=np.zeros((n, 3), np.float32) if base is None else base.translation.astype(np.float32),
        face=np.clip(features[:, PARTS["arkit"]], 0.0, 1.0),
        vad=vad,
        state=ConversationState.from_vad(vad),
        fps=fps if fps is not None else (base.fps if base is not None else 30.0),
    )


def shape_bounds(mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(FEATURE_DIM,) normalised low and high bounds of the ARKit shapes, where ``decode`` clips
    them to [0, 1]; infinite elsewhere. Motion past them shows the same as motion at them."""
    low = np.full(FEATURE_DIM, -np.inf, np.float32)
    high = np.full(FEATURE_DIM, np.inf, np.float32)
    columns = PARTS["arkit"]
    low[columns] = (0.0 - mean[columns]) / std[columns]
    high[columns] = (1.0 - mean[columns]) / std[columns]
    return low, high


def feature_mask(joints: np.ndarray | None = None, face: np.ndarray | None = None) -> np.ndarray:
    """(FEATURE_DIM,) bool: True where a corpus has real data. ``joints`` (55,) and ``face`` (52,)
    say which joints and ARKit channels it has (None: all); voice activity always comes from the
    audio, so it is always present."""
    joints = np.ones(NUM_JOINTS, bool) if joints is None else np.asarray(joints, bool)
    face = np.ones(NUM_BLENDSHAPES, bool) if face is None else np.asarray(face, bool)
    if joints.shape != (NUM_JOINTS,) or face.shape != (NUM_BLENDSHAPES,):
        raise ValueError(f"masks must be ({NUM_JOINTS},) and ({NUM_BLENDSHAPES},), got {joints.shape}, {face.shape}")
    mask = np.ones(FEATURE_DIM, bool)
    mask[_ROTATION_COLUMNS] = np.repeat(joints[_COVERED_INDEX], SIXD)
    mask[PARTS["arkit"]] = face
    return mask


@dataclasses.dataclass(frozen=True)
class FeatureStats:
    """Per-dimension mean and standard deviation of the features, and the frames each came from.

    ``normalise`` maps features to roughly zero mean and unit spread; a dimension no data covered
    (count 0) or a constant one keeps mean 0 / std 1 or its mean / std 1. ``denormalise`` gives a
    constant dimension its constant back, whatever a network said there (see ``constant``).
    """

    mean: np.ndarray
    std: np.ndarray
    count: np.ndarray

    @classmethod
    def fit(cls, batches: Iterable[tuple[np.ndarray, np.ndarray]]) -> FeatureStats:
        """From ``(features (T, D), mask (D,))`` pairs; masked-out columns are not counted.
        Sums in float64 around a running shift, so hours of frames keep their precision."""
        total = np.zeros(FEATURE_DIM)
        total_sq = np.zeros(FEATURE_DIM)
        count = np.zeros(FEATURE_DIM)
        shift: np.ndarray | None = None
        for features, mask in batches:
            x = np.asarray(features, np.float64).reshape(-1, FEATURE_DIM)
            if len(x) == 0:
                continue
            if shift is None:
                shift = x[0].copy()
            m = np.asarray(mask, bool)
            d = (x - shift) * m
            total += d.sum(0)
            total_sq += (d * d).sum(0)
            count += len(x) * m
        shift = np.zeros(FEATURE_DIM) if shift is None else shift
        seen = count > 0
        safe = np.where(seen, count, 1.0)
        mean = np.where(seen, shift + total / safe, 0.0)
        var = np.where(seen, np.maximum(total_sq / safe - (total / safe) ** 2, 0.0), 1.0)
        std = np.sqrt(var)
        std = np.where(std < STD_FLOOR, 1.0, std)
        return cls(mean.astype(np.float32), std.astype(np.float32), count.astype(np.int64))

    def normalise(self, features: np.ndarray) -> np.ndarray:
        return ((np.asarray(features, np.float32) - self.mean) / self.std).astype(np.float32)

    @property
    def constant(self) -> np.ndarray:
        """(FEATURE_DIM,) bool: the dimensions the data covered but never moved (a finger's bend
        about a second axis, an ARKit shape no take used), which ``fit`` scales by 1. A network
        has nothing to learn there, and its error comes out at that unit scale: a twist of a few
        degrees every frame, a brow that twitches. Every feature lies in [-1, 1], so a measured
        spread is below 1 and a spread of exactly 1 marks the floor."""
        return (self.count > 0) & (self.std == 1.0)

    def denormalise(self, normalised: np.ndarray) -> np.ndarray:
        """Features from normalised ones, the constant dimensions at their constant."""
        out = np.asarray(normalised, np.float32) * self.std + self.mean
        constant = self.constant
        out[..., constant] = self.mean[constant]
        return out.astype(np.float32)

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> FeatureStats:
        """From a model folder's ``normalisation.npz``: ``mean``, ``std`` and ``count`` (folders
        exported before counts were written lack it). Without counts, a rotation whose six dimensions are all
        mean 0 / std 1 is taken as one the data lacked (a seen rotation has a unit first row), and
        everything else as seen."""
        mean, std = np.asarray(arrays["mean"], np.float32), np.asarray(arrays["std"], np.float32)
        if "count" in arrays:
            count = np.asarray(arrays["count"], np.int64)
        else:
            unseen = (mean == 0) & (std == 1)
            blocks = unseen[_ROTATION_COLUMNS].reshape(-1, SIXD).all(axis=1)
            count = np.ones(FEATURE_DIM, np.int64)
            count[_ROTATION_COLUMNS] = np.repeat(~blocks, SIXD)
        return cls(mean, std, count)

    def to_json(self) -> dict[str, Any]:
        return {
            "layout": layout(),
            "names": feature_names(),
            "mean": [float(v) for v in self.mean],
            "std": [float(v) for v in self.std],
            "count": [int(v) for v in self.count],
        }

    @classmethod
    def from_json(cls, data: dict[str, Any], source: str = "statistics") -> FeatureStats:
        """Read ``to_json``'s form; a wrong layout or length is an ``InputFileError`` naming ``source``."""
        try:
            version = int(data["layout"]["version"])
            mean, std, count = (np.asarray(data[k], np.float64) for k in ("mean", "std", "count"))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputFileError(source, f"not feature statistics (missing or bad {exc})") from None
        if version != LAYOUT_VERSION:
            raise InputFileError(source, f"feature layout version {version}, this convodrive reads {LAYOUT_VERSION}")
        if not mean.shape == std.shape == count.shape == (FEATURE_DIM,):
            raise InputFileError(source, f"statistics must have {FEATURE_DIM} values each, got {mean.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std)) and np.all(std > 0)):
            raise InputFileError(source, "statistics hold NaN, infinite or non-positive spreads")
        return cls(mean.astype(np.float32), std.astype(np.float32), count.astype(np.int64))

    def save(self, path: str | os.PathLike[str]) -> Path:
        path = Path(path)
        write_text_atomic(path, json.dumps(self.to_json()) + "\n")
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> FeatureStats:
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputFileError(path, "no such file") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputFileError(path, f"not readable JSON ({exc.__class__.__name__})") from None
        if not isinstance(data, dict):
            raise InputFileError(path, "not feature statistics (expected a JSON object)")
        return cls.from_json(data, str(path))
