"""Seamless Interaction (Meta, 2025): dyadic conversations, one audio and one SMPL-H file per participant.

Layout: the files of the data set's shards, extracted into one folder (any depth)::

    <vendor>_<session>_<interaction>_<participant>.wav   the participant's own microphone (48 kHz)
    <vendor>_<session>_<interaction>_<participant>.npz   SMPL-H body and hands at 30 Hz (+ other features)

The two participants of one interaction (same name up to the final ``_P...`` field) form a dyad:
each becomes a conversation seen from their side (self = their microphone and motion, partner =
the other's microphone), both in one group, so they share a split. A participant whose partner is
absent from the folder is imported with a silent partner, and the manifest says so.

The npz key names are not verified against the released files, so they live in one table,
``KEYS``: each canonical field lists the names tried, in order; a file with none of them is one
line listing the keys it has. SMPL-H has no jaw or eye joints and no ARKit face: those are masked.
"""

from __future__ import annotations

import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from convodrive import FPS
from convodrive.audio.source import AudioSource, ChannelMap, DyadicAudio
from convodrive.corpus.importers.common import (
    ALL_FACE,
    SMPLH_JOINTS,
    pose_from_joints,
    read_numeric_npz,
    recording,
    upright_root,
)
from convodrive.corpus.importers.options import ImportOptions
from convodrive.corpus.manifest import safe_id
from convodrive.corpus.writer import Recording
from convodrive.plumbing.errors import InputFileError

LICENCE = "CC BY-NC 4.0 (Seamless Interaction): non-commercial"

KEYS: dict[str, tuple[str, ...]] = {
    "poses": ("smplh:poses", "poses", "smplh_poses"),
    "global_orient": ("smplh:global_orient", "global_orient", "root_orient"),
    "body_pose": ("smplh:body_pose", "body_pose", "pose_body"),
    "left_hand_pose": ("smplh:left_hand_pose", "left_hand_pose", "pose_hand_left"),
    "right_hand_pose": ("smplh:right_hand_pose", "right_hand_pose", "pose_hand_right"),
    "translation": ("smplh:translation", "smplh:transl", "transl", "trans", "translation"),
    "fps": ("smplh:fps", "fps", "mocap_framerate", "mocap_frame_rate"),
}
"""Canonical field -> npz key names tried in order. ``poses`` (T, 156: 52 SMPL-H joints) is used
when present; otherwise the four parts (T, 3), (T, 63), (T, 45), (T, 45) are joined."""
_PARTICIPANT = re.compile(r"^(?P<dyad>.+)_(?P<who>P[^_]+)$")


def find(src: Path, options: ImportOptions) -> list[tuple[Path, Path | None, str]]:
    """Per participant: their npz, their partner's npz (None when absent), and the dyad's name."""
    dyads: dict[str, list[Path]] = defaultdict(list)
    for npz in sorted(src.rglob("*.npz")):
        if not npz.with_suffix(".wav").is_file():
            raise InputFileError(npz, f"no audio beside it (expected {npz.with_suffix('.wav').name})")
        match = _PARTICIPANT.match(npz.stem)
        dyads[match["dyad"] if match else npz.stem].append(npz)
    if not dyads:
        raise InputFileError(src, "holds no Seamless Interaction files (expected <interaction>_<P...>.npz with .wav)")
    items: list[tuple[Path, Path | None, str]] = []
    for dyad, members in dyads.items():
        if len(members) > 2:
            raise InputFileError(members[2], f"a third participant in interaction {dyad} (a dyad has two)")
        for i, npz in enumerate(members):
            items.append((npz, members[1 - i] if len(members) == 2 else None, dyad))
    return items


def _first(data: dict[str, np.ndarray], field: str) -> np.ndarray | None:
    return next((data[k] for k in KEYS[field] if k in data), None)


def read_smplh(path: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """(T, 52 * 3) SMPL-H axis-angles, (T, 3) translation and the frame rate (30 when not given),
    through ``KEYS``."""
    data, names = read_numeric_npz(path)
    given = _first(data, "fps")
    if given is not None and given.size != 1:
        raise InputFileError(path, f"frame rate has shape {given.shape}, expected one number")
    fps = float(given.reshape(-1)[0]) if given is not None else float(FPS)
    if not 1.0 <= fps <= 1000.0:
        raise InputFileError(path, f"frame rate {fps:g} is not a frame rate")
    poses = _first(data, "poses")
    parts = [_first(data, f) for f in ("global_orient", "body_pose", "left_hand_pose", "right_hand_pose")]
    if poses is None and any(p is None for p in parts):
        raise InputFileError(
            path, f"no SMPL-H pose arrays under the names tried (see KEYS); it has {', '.join(names) or 'nothing'}"
        )
    trans = _first(data, "translation")
    try:
        if poses is None:
            n = len(parts[0])  # type: ignore[arg-type]
            poses = np.concatenate([np.asarray(p, np.float64).reshape(n, -1) for p in parts if p is not None], axis=1)
        poses = np.asarray(poses, np.float64).reshape(len(poses), -1)
        trans = np.zeros((len(poses), 3)) if trans is None else np.asarray(trans, np.float64).reshape(-1, 3)
    except (ValueError, TypeError) as exc:  # 0-d arrays, parts of different lengths, (T, 2) translations
        raise InputFileError(path, f"SMPL-H arrays of mismatched shapes ({exc})") from None
    if len(trans) != len(poses):
        raise InputFileError(path, f"translation has {len(trans)} frames, poses {len(poses)}")
    return poses, trans, fps


def _mono(path: Path) -> np.ndarray:
    return AudioSource(path, ChannelMap(0, None)).read_all().self_voice


def load(item: tuple[Path, Path | None, str], options: ImportOptions) -> list[Recording]:
    npz, partner_npz, dyad = item
    wav = npz.with_suffix(".wav")
    poses, trans, fps = read_smplh(npz)
    pose, missing = pose_from_joints(poses, SMPLH_JOINTS, npz)
    pose, translation = upright_root(pose, trans)
    own = _mono(wav)
    other = np.zeros_like(own)
    if partner_npz is not None:
        theirs = _mono(partner_npz.with_suffix(".wav"))[: len(own)]
        other[: len(theirs)] = theirs
    participant = _PARTICIPANT.match(npz.stem)
    return [
        recording(
            safe_id(npz.stem),
            DyadicAudio(own, other, str(wav)),
            pose,
            translation,
            None,
            speaker=options.speaker or (participant["who"] if participant else npz.stem),
            audio_path=wav,
            motion_path=npz,
            missing_joints=missing,
            missing_face=ALL_FACE,
            group=safe_id(dyad),
            metadata={
                "source": "seamless",
                "partner": partner_npz.stem if partner_npz is not None else None,
                "face": "not in SMPL-H: masked",
            },
            fps=fps,
        )
    ]
