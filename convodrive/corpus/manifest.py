"""The corpus manifest (``manifest.json``): what the folder holds, read and checked in one place.

The manifest is written last, so a folder without one is an unfinished corpus. Each conversation
entry names its shard, its audio file, its frame count, takes, speaker label, split and the
channels it lacks; the shard list carries each file's size, so a truncated shard is caught before
it is opened.
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES
from convodrive.plumbing.errors import InputFileError

FORMAT = "convodrive.corpus"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
SPLITS = ("train", "val", "test")
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")


def check_id(text: str) -> str:
    """Conversation ids become file names and array keys: letters, digits, ``_``, ``.`` and ``-``."""
    if not _ID.match(text):
        raise ValueError(f"conversation id {text!r} must be 1-128 letters, digits, '_', '.' or '-'")
    return text


def safe_id(text: str) -> str:
    """An id made from arbitrary text (a file name): other characters become ``-``."""
    cleaned = re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-.") or "x"
    return check_id(cleaned[:128])


@dataclasses.dataclass(frozen=True)
class ConversationInfo:
    """One conversation seen from one side (channel 0 is the person whose motion is stored)."""

    id: str
    split: str
    group: str
    """Conversations of one group (both sides of one dyad) always share a split."""
    speaker: str
    frames: int
    takes: int
    shard: str
    audio: str
    missing_joints: tuple[str, ...] = ()
    missing_face: tuple[str, ...] = ()
    metadata: dict[str, Any] = dataclasses.field(default_factory=dict)
    stratum: str = ""
    """The maker's kind of conversation (``synthesised``, ``paired``, ``recorded``; empty for an
    import): splits are drawn within each, and eval scores each apart."""

    @property
    def joint_mask(self) -> np.ndarray:
        mask = np.ones(len(JOINT_NAMES), bool)
        mask[[JOINT_INDEX[j] for j in self.missing_joints]] = False
        return mask

    @property
    def face_mask(self) -> np.ndarray:
        mask = np.ones(len(ARKIT_NAMES), bool)
        mask[[BLENDSHAPE_INDEX[c] for c in self.missing_face]] = False
        return mask

    def to_json(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["missing_joints"] = list(self.missing_joints)
        data["missing_face"] = list(self.missing_face)
        return data

    @classmethod
    def from_json(cls, data: Any, source: Path) -> ConversationInfo:
        try:
            info = cls(
                id=check_id(str(data["id"])),
                split=str(data["split"]),
                group=str(data["group"]),
                speaker=str(data["speaker"]),
                frames=int(data["frames"]),
                takes=int(data["takes"]),
                shard=str(data["shard"]),
                audio=str(data["audio"]),
                missing_joints=tuple(str(j) for j in data.get("missing_joints", ())),
                missing_face=tuple(str(c) for c in data.get("missing_face", ())),
                metadata=dict(data.get("metadata", {})),
                stratum=str(data.get("stratum", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputFileError(source, f"bad conversation entry ({exc.__class__.__name__}: {exc})") from None
        if info.split not in SPLITS:
            raise InputFileError(
                source, f"conversation {info.id}: split {info.split!r} is not one of {', '.join(SPLITS)}"
            )
        if info.frames < 1 or info.takes < 1:
            raise InputFileError(source, f"conversation {info.id}: needs at least one frame and one take")
        unknown = [j for j in info.missing_joints if j not in JOINT_INDEX] + [
            c for c in info.missing_face if c not in BLENDSHAPE_INDEX
        ]
        if unknown:
            raise InputFileError(source, f"conversation {info.id}: unknown channel {unknown[0]!r} in its masks")
        for rel in (info.shard, info.audio):
            if Path(rel).is_absolute() or ".." in Path(rel).parts:
                raise InputFileError(source, f"conversation {info.id}: path {rel!r} leaves the corpus folder")
        return info


def read_manifest(folder: Path) -> dict[str, Any]:
    """The manifest's JSON, its format and version checked."""
    path = folder / MANIFEST
    if not folder.is_dir():
        raise InputFileError(folder, "no such corpus folder" if not folder.exists() else "not a folder")
    if not path.is_file():
        raise InputFileError(folder, f"no {MANIFEST}: not a corpus, or one whose writing did not finish")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(path, f"not readable JSON ({exc.__class__.__name__})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputFileError(path, f"not a convodrive corpus manifest (no format {FORMAT!r})")
    if data.get("version") != FORMAT_VERSION:
        raise InputFileError(
            path,
            f"corpus format version {data.get('version')} is not supported (this convodrive reads {FORMAT_VERSION})",
        )
    for key in ("conversations", "shards"):
        if not isinstance(data.get(key), list):
            raise InputFileError(path, f"manifest has no {key!r} list")
    return data


def assign_splits(
    groups: Sequence[str], seed: int, fractions: tuple[float, float] = (0.1, 0.1), fixed: dict[str, str] | None = None
) -> dict[str, str]:
    """Split groups into train/val/test: ``fractions`` of them to val and test (at least one each
    once there are three groups), the rest to train; a seeded shuffle of the sorted groups, so the
    split depends only on the seed and the set of groups. ``fixed`` keeps a split a source prescribes."""
    fixed = dict(fixed or {})
    free = sorted(set(groups) - set(fixed))
    order = [free[i] for i in np.random.default_rng(seed).permutation(len(free))]
    n = len(order)
    n_val = max(1, round(fractions[0] * n)) if n >= 3 else 0
    n_test = max(1, round(fractions[1] * n)) if n >= 2 else 0
    out = dict(fixed)
    for i, group in enumerate(order):
        out[group] = "test" if i < n_test else "val" if i < n_test + n_val else "train"
    return out
