"""SHOW (the TalkSHOW / ProbTalk data set): per-clip SMPL-X fits of four talk-show speakers.

Layout (``ExpressiveWholeBodyDatasetReleaseV1.0/``)::

    <speaker>/<video>/<clip>/<clip>.pkl and <clip>.wav
    <speaker>/<video>/<train|val|test>/<clip>/...     (after TalkSHOW's apply_split: kept as the split)

Each pickle holds ``global_orient`` (T, 1, 3) in camera coordinates, ``body_pose_axis`` (T, 63)
for SMPL-X joints 1-21, ``jaw_pose``, ``leye_pose``, ``reye_pose`` (T, 3), ``transl`` (T, 3),
FLAME ``expression`` (T, 100), and the hands as 12 MANO PCA coefficients each
(``left_hand_pose``, ``right_hand_pose`` (T, 12)), plus fitting metadata, including torch tensors
(``losses_to_log``) that are dropped unread. Pickles go through the restricted unpickler.

Hands: PCA coefficients become joint rotations only through MANO's components, which the user
must bring (``--mano``: an SMPL-X model ``.npz`` with ``hands_componentsl/r`` and
``hands_meanl/r``, or TalkSHOW's ``hand_component.json`` with ``left``/``right``). Without them the
hands are masked. The face is masked (FLAME, not ARKit). The audio (22 kHz stereo from the show)
is the speaker's: its channels are mixed and the partner is silent. Clips of one video share a
split.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.corpus.importers.common import (
    ALL_FACE,
    HAND_JOINTS,
    SMPLX_JOINTS,
    pose_from_joints,
    read_speaker_audio,
    recording,
    upright_root,
)
from convodrive.corpus.importers.options import ImportOptions
from convodrive.corpus.importers.pickles import drop_skipped, load_pickle
from convodrive.corpus.manifest import SPLITS, safe_id
from convodrive.corpus.writer import Recording
from convodrive.plumbing.errors import InputFileError

LICENCE = "SHOW data set licence (talkshow.is.tue.mpg.de): non-commercial research"

HAND_DIM = 45


def find(src: Path, options: ImportOptions) -> list[tuple[Path, Path, str, str, str | None]]:
    """Each clip's pickle, audio, speaker, group (speaker/video) and prescribed split."""
    items = []
    for pkl in sorted(src.rglob("*.pkl")):
        wav = pkl.with_suffix(".wav")
        if not wav.is_file():
            raise InputFileError(pkl, f"no audio beside it (expected {wav.name})")
        parts = pkl.relative_to(src).parts
        speaker = options.speaker or (parts[0] if len(parts) > 1 else "show")
        group = "/".join(parts[:2]) if len(parts) > 2 else pkl.stem
        split = next((p for p in parts[:-1] if p in SPLITS), None)
        items.append((pkl, wav, speaker, group, split))
    if not items:
        raise InputFileError(src, "holds no SHOW clips (expected <speaker>/<video>/<clip>/<clip>.pkl)")
    if options.mano is not None:
        load_hand_components(options.mano)  # a bad file fails before anything is written
    return items


def load_hand_components(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """Per side, MANO's PCA components (k, 45) and mean pose (45,) (None when the file has none)."""
    if not path.is_file():
        raise InputFileError(path, "no such file")
    try:
        if path.suffix.lower() == ".json":
            data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
            keys = {"left": ("left", "left_mean"), "right": ("right", "right_mean")}
        else:
            with np.load(path, allow_pickle=False) as npz:
                data = {k: npz[k] for k in npz.files if k.startswith("hands_")}
            keys = {"left": ("hands_componentsl", "hands_meanl"), "right": ("hands_componentsr", "hands_meanr")}
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, ValueError, zipfile.BadZipFile) as exc:
        raise InputFileError(path, f"not readable hand components ({exc.__class__.__name__})") from None
    out = {}
    for side, (comp_key, mean_key) in keys.items():
        if comp_key not in data:
            raise InputFileError(
                path, f"no {comp_key!r} (hand PCA components: an SMPL-X model .npz or hand_component.json)"
            )
        comp = np.asarray(data[comp_key], np.float64)
        mean = np.asarray(data[mean_key], np.float64).reshape(-1) if mean_key in data else None
        if comp.ndim != 2 or comp.shape[1] != HAND_DIM or (mean is not None and mean.shape != (HAND_DIM,)):
            raise InputFileError(path, f"{comp_key!r} must be (k, 45) with a (45,) mean, got {comp.shape}")
        out[side] = (comp, mean)
    return out


def _array(data: dict[str, Any], key: str, path: Path, width: int) -> np.ndarray:
    if key not in data:
        raise InputFileError(path, f"no {key!r} in the pickle (has {', '.join(sorted(map(str, data)))})")
    try:
        value = np.asarray(data[key], np.float64)
    except (ValueError, TypeError, OverflowError):
        raise InputFileError(path, f"{key!r} is not an array of numbers (got {type(data[key]).__name__})") from None
    if value.size % width or value.ndim < 1:
        raise InputFileError(path, f"{key!r} has shape {value.shape}, expected (frames, {width})")
    return value.reshape(len(value), width)


def hands_axis_angle(
    pca: np.ndarray, components: np.ndarray, mean: np.ndarray | None, path: Path, key: str
) -> np.ndarray:
    """(T, 45) hand joint axis-angles from (T, k) PCA coefficients: mean + coefficients @ components[:k]."""
    k = pca.shape[1]
    if k > len(components):
        raise InputFileError(path, f"{key!r} has {k} PCA coefficients but the hand components only {len(components)}")
    out = pca @ components[:k]
    return out + mean if mean is not None else out


def load(item: tuple[Path, Path, str, str, str | None], options: ImportOptions) -> list[Recording]:
    pkl, wav, speaker, group, split = item
    raw = load_pickle(pkl)
    data, dropped = drop_skipped(raw)
    if not isinstance(data, dict):
        raise InputFileError(pkl, f"expected a dict of arrays, got {type(raw).__name__}")
    body = _array(data, "body_pose_axis" if "body_pose_axis" in data else "body_pose", pkl, 63)
    n = len(body)
    parts = {
        "pelvis": _array(data, "global_orient", pkl, 3),
        "jaw": _array(data, "jaw_pose", pkl, 3),
        "left_eye_smplhf": _array(data, "leye_pose", pkl, 3),
        "right_eye_smplhf": _array(data, "reye_pose", pkl, 3),
    }
    for key, value in parts.items():
        if len(value) != n:
            raise InputFileError(pkl, f"{key} has {len(value)} frames, body_pose_axis {n}")
    values = np.zeros((n, len(SMPLX_JOINTS), 3))
    index = {name: i for i, name in enumerate(SMPLX_JOINTS)}
    values[:, 1:22] = body.reshape(n, 21, 3)
    for name, value in parts.items():
        values[:, index[name]] = value
    missing_hands: tuple[str, ...] = ()
    note = "hands from the MANO components given"
    hand_components = load_hand_components(options.mano) if options.mano is not None else None
    for side in ("left", "right"):
        key = f"{side}_hand_pose"
        width = int(np.shape(data[key])[-1]) if key in data and np.ndim(data[key]) else 0
        if not 1 <= width <= HAND_DIM:
            raise InputFileError(pkl, f"{key!r} must be (frames, k) PCA coefficients or (frames, 45) axis-angles")
        hand = _array(data, key, pkl, width)
        if len(hand) != n:
            raise InputFileError(pkl, f"{key} has {len(hand)} frames, body_pose_axis {n}")
        if hand.shape[1] == HAND_DIM:  # already axis-angle
            rot = hand
        elif hand_components is None:
            missing_hands += HAND_JOINTS[side]
            note = "hands are 12 MANO PCA coefficients and no --mano components were given: masked"
            continue
        else:
            rot = hands_axis_angle(hand, *hand_components[side], pkl, key)
        values[:, [index[j] for j in HAND_JOINTS[side]]] = rot.reshape(n, 15, 3)
    pose, missing = pose_from_joints(values.reshape(n, -1), SMPLX_JOINTS, pkl)
    trans = _array(data, "transl", pkl, 3) if "transl" in data else np.zeros((n, 3))
    pose, translation = upright_root(pose, trans)
    return [
        recording(
            safe_id(pkl.stem),
            read_speaker_audio(wav),
            pose,
            translation,
            None,
            speaker=speaker,
            audio_path=wav,
            motion_path=pkl,
            missing_joints=missing + missing_hands,
            missing_face=ALL_FACE,
            group=group,
            split=split,
            metadata={
                "source": "show",
                "face": "FLAME expressions (not ARKit): masked",
                "hands": note,
                "dropped": dropped,
            },
        )
    ]
