"""BEAT2 (BEATX, the EMAGE data set): SMPL-X motion of one speaker with 16 kHz speech.

Layout (``beat_english_v2.0.0/``), or the ``.npz`` and ``.wav`` side by side in any folder::

    smplxflame_30/<clip>.npz   poses (T, 165): SMPL-X's 55 joints in SMPL-X order, axis-angle;
                               trans (T, 3); expressions (T, 100) FLAME; betas; mocap_frame_rate
    wave16k/<clip>.wav         the speaker, mono 16 kHz
    train_test_split.csv       optional: columns id, type (train / val / test / additional)

Clips are named ``<n>_<speaker>_<...>``: the speaker label is the second field. Monologues: the
partner channel is silent. FLAME expressions cannot become ARKit channels without the FLAME basis,
so the 52 face channels are masked; jaw and eyes come from the skeleton.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from convodrive import FPS
from convodrive.corpus.importers.common import (
    ALL_FACE,
    SMPLX_JOINTS,
    pose_from_joints,
    read_numeric_npz,
    read_speaker_audio,
    recording,
    upright_root,
)
from convodrive.corpus.importers.options import ImportOptions
from convodrive.corpus.manifest import safe_id
from convodrive.corpus.writer import Recording
from convodrive.plumbing.errors import InputFileError

LICENCE = "CC BY-NC 4.0 (BEAT2): non-commercial"

_SPLIT_NAMES = {"train": "train", "val": "val", "test": "test", "additional": "train"}


def find(src: Path, options: ImportOptions) -> list[tuple[Path, Path, str | None]]:
    """Each clip's motion, audio and prescribed split."""
    motion_dir = src / "smplxflame_30" if (src / "smplxflame_30").is_dir() else src
    audio_dir = src / "wave16k" if (src / "wave16k").is_dir() else motion_dir
    splits = _read_splits(src / "train_test_split.csv")
    items = []
    for npz in sorted(motion_dir.glob("*.npz")):
        wav = audio_dir / f"{npz.stem}.wav"
        if not wav.is_file():
            raise InputFileError(npz, f"no audio beside it (expected {wav})")
        items.append((npz, wav, splits.get(npz.stem)))
    if not items:
        raise InputFileError(src, "holds no BEAT2 clips (expected smplxflame_30/*.npz and wave16k/*.wav)")
    return items


def _read_splits(path: Path) -> dict[str, str]:
    if not path.is_file():
        return {}
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputFileError(path, f"not a readable CSV ({exc.__class__.__name__})") from None
    out = {}
    for row in rows:
        name, kind = (row.get("id") or "").strip(), (row.get("type") or "").strip().lower()
        if name and kind in _SPLIT_NAMES:
            out[name] = _SPLIT_NAMES[kind]
    return out


def load(item: tuple[Path, Path, str | None], options: ImportOptions) -> list[Recording]:
    npz, wav, split = item
    data, names = read_numeric_npz(npz, "BEAT2 .npz")
    if "poses" not in data:
        raise InputFileError(npz, f"no numeric 'poses' array (has {', '.join(names) or 'nothing'})")
    poses = data["poses"]
    trans = data["trans"] if "trans" in data else np.zeros((len(poses), 3))
    given = data.get("mocap_frame_rate", np.array(float(FPS)))
    if given.size != 1:
        raise InputFileError(npz, f"mocap_frame_rate has shape {given.shape}, expected one number")
    rate = float(given.reshape(-1)[0])
    if not 1.0 <= rate <= 1000.0:
        raise InputFileError(npz, f"mocap_frame_rate {rate:g} is not a frame rate")
    if trans.shape != (len(poses), 3):
        raise InputFileError(npz, f"'trans' has shape {trans.shape}, expected ({len(poses)}, 3)")
    pose, missing = pose_from_joints(poses, SMPLX_JOINTS, npz)
    pose, translation = upright_root(pose, trans)
    fields = npz.stem.split("_")
    speaker = options.speaker or (fields[1] if len(fields) > 1 and fields[1] else "beat2")
    return [
        recording(
            safe_id(npz.stem),
            read_speaker_audio(wav),
            pose,
            translation,
            None,
            speaker=speaker,
            audio_path=wav,
            motion_path=npz,
            missing_joints=missing,
            missing_face=ALL_FACE,
            split=split,
            metadata={"source": "beat2", "face": "FLAME expressions (not ARKit): masked"},
            fps=rate,
        )
    ]
