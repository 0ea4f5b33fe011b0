"""Writing a corpus: recordings in, shards, audio files and the manifest out.

Every file is written to a temporary name and renamed (``plumbing.atomic``); the manifest comes
last, and a writer that fails removes what it wrote, so a folder holds a whole corpus or none.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import soundfile as sf

from convodrive import FPS
from convodrive.audio.logmel import DEFAULT_SPEC, MelSpec, log_mel
from convodrive.audio.source import ANALYSIS_RATE, motion_frames_for
from convodrive.corpus.manifest import (
    FORMAT,
    FORMAT_VERSION,
    MANIFEST,
    SPLITS,
    ConversationInfo,
    assign_splits,
    check_id,
)
from convodrive.corpus.shards import write_shard
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_NAMES
from convodrive.plumbing.atomic import atomic_path, write_text_atomic
from convodrive.plumbing.errors import UserError

SHARD_BYTES = 256 << 20
"""A shard is closed once it holds this much; big enough to keep file counts low, small enough to copy."""


@dataclasses.dataclass
class Recording:
    """One conversation from one side, as a maker or an importer hands it to the writer."""

    id: str
    audio: np.ndarray
    """(n, 2) samples at 16 kHz in [-1, 1]: channel 0 the person whose motion this is, 1 the partner."""
    takes: Sequence[MotionClip]
    """K >= 1 clips of that person's motion, each ``motion_frames_for(n / 16000)`` frames at 30 fps."""
    speaker: str
    group: str | None = None
    """Recordings sharing a group share a split (the two sides of one dyad); default: the id."""
    missing_joints: tuple[str, ...] = ()
    missing_face: tuple[str, ...] = ()
    split: str | None = None
    """A split the source prescribes; None lets the writer draw one."""
    metadata: dict[str, Any] = dataclasses.field(default_factory=dict)
    stratum: str = ""
    """Splits are drawn within each stratum (a maker's kind of conversation), so that the
    conversations of one kind keep their splits whatever else the corpus holds: adding recorded
    voices must not move a synthesised test conversation into train."""


@dataclasses.dataclass
class Prepared:
    """A recording turned into what is stored: 16-bit audio and the shard arrays (features included).
    Made by ``prepare``, which parallel makers run in their worker processes."""

    recording: Recording
    pcm: np.ndarray
    arrays: dict[str, np.ndarray]

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays.values())


def to_pcm16(audio: np.ndarray) -> np.ndarray:
    """16-bit samples, as the corpus stores audio (full scale 32768, clipped)."""
    return np.clip(np.round(np.asarray(audio, np.float64) * 32768.0), -32768, 32767).astype(np.int16)


def quantise(audio: np.ndarray) -> np.ndarray:
    """float32 audio exactly as a reader of the stored 16-bit WAV gets it back."""
    return to_pcm16(audio).astype(np.float32) / np.float32(32768.0)


def prepare(rec: Recording, spec: MelSpec = DEFAULT_SPEC) -> Prepared:
    """Check a recording, quantise its audio to 16 bits and compute its log-mel features from the
    quantised samples, exactly as a reader of the stored WAV will get them."""
    check_id(rec.id)
    audio = np.asarray(rec.audio, np.float32)
    if audio.ndim != 2 or audio.shape[1] != 2 or len(audio) == 0:
        raise ValueError(f"{rec.id}: audio must be (n, 2) samples, got {audio.shape}")
    if not rec.takes:
        raise ValueError(f"{rec.id}: a recording needs at least one take")
    frames = motion_frames_for(len(audio) / ANALYSIS_RATE)
    for k, take in enumerate(rec.takes):
        if take.num_frames != frames:
            raise ValueError(f"{rec.id}: take {k} has {take.num_frames} frames, its audio {frames}")
        if abs(take.fps - FPS) > 1e-6:
            raise ValueError(f"{rec.id}: take {k} runs at {take.fps} fps, the corpus at {FPS}")
    for name, valid in (("joint", JOINT_NAMES), ("face channel", ARKIT_NAMES)):
        given = rec.missing_joints if name == "joint" else rec.missing_face
        if set(given) - set(valid):
            raise ValueError(f"{rec.id}: unknown {name} {sorted(set(given) - set(valid))[0]!r}")
    if rec.split is not None and rec.split not in SPLITS:
        raise ValueError(f"{rec.id}: split {rec.split!r} is not one of {SPLITS}")
    pcm = to_pcm16(audio)
    arrays: dict[str, np.ndarray] = {
        f"{rec.id}/pose": np.stack([t.pose for t in rec.takes]).astype(np.float32),
        f"{rec.id}/translation": np.stack([t.translation for t in rec.takes]).astype(np.float32),
        f"{rec.id}/face": np.stack([t.face for t in rec.takes]).astype(np.float32),
        f"{rec.id}/vad": np.stack([t.vad for t in rec.takes]).astype(np.float32),
        f"{rec.id}/state": np.stack([t.state for t in rec.takes]).astype(np.int8),
        f"{rec.id}/mel": log_mel(pcm.astype(np.float32) / np.float32(32768.0), frames, spec),
    }
    for key, value in arrays.items():
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            raise ValueError(f"{key} holds NaN or infinite values")
    return Prepared(rec, pcm, arrays)


class CorpusWriter:
    """Writes one corpus folder. Use as a context manager: leaving it with an error removes every
    file it wrote; ``close`` (called on a clean exit) writes the manifest."""

    def __init__(
        self,
        folder: str | Path,
        source: dict[str, Any],
        seed: int = 0,
        spec: MelSpec = DEFAULT_SPEC,
        shard_bytes: int = SHARD_BYTES,
        licence: str = "that of the source data",
    ) -> None:
        """``source`` says where the data came from (kind, command, options); ``licence`` the terms
        of the data, which models trained on it inherit (a model card quotes it)."""
        self.folder = Path(folder)
        if self.folder.exists() and (not self.folder.is_dir() or any(self.folder.iterdir())):
            raise UserError(f"{self.folder}: already exists and is not an empty folder; choose a new one")
        self._created = not self.folder.exists()
        self.source = dict(source)
        self.licence = licence
        self.seed = seed
        self.spec = spec
        self.shard_bytes = shard_bytes
        self._written: list[Path] = []
        self._pending: list[Prepared] = []
        self._entries: list[dict[str, Any]] = []
        self._shards: list[dict[str, Any]] = []
        self._ids: set[str] = set()
        self._closed = False
        try:
            (self.folder / "audio").mkdir(parents=True, exist_ok=True)
            (self.folder / "shards").mkdir(exist_ok=True)
        except OSError as exc:
            raise UserError(f"{self.folder}: cannot create the corpus folder ({exc.strerror})") from None

    def __enter__(self) -> CorpusWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()

    def add(self, item: Recording | Prepared) -> None:
        prepared = item if isinstance(item, Prepared) else prepare(item, self.spec)
        rec = prepared.recording
        if rec.id in self._ids:
            raise ValueError(f"conversation id {rec.id!r} appears twice")
        self._ids.add(rec.id)
        wav = self.folder / "audio" / f"{rec.id}.wav"
        self._written.append(wav)
        with atomic_path(wav) as tmp:
            sf.write(tmp, prepared.pcm, ANALYSIS_RATE, subtype="PCM_16", format="WAV")
        self._pending.append(prepared)
        if sum(p.nbytes for p in self._pending) >= self.shard_bytes:
            self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        rel = f"shards/shard-{len(self._shards):05d}.npz"
        path = self.folder / rel
        self._written.append(path)
        arrays = {k: v for p in self._pending for k, v in p.arrays.items()}
        size = write_shard(path, arrays)
        ids = [p.recording.id for p in self._pending]
        self._shards.append({"path": rel, "bytes": size, "conversations": ids})
        for p in self._pending:
            rec = p.recording
            self._entries.append(
                {
                    "id": rec.id,
                    "group": rec.group or rec.id,
                    "split": rec.split,
                    "stratum": rec.stratum,
                    "speaker": rec.speaker,
                    "frames": int(p.arrays[f"{rec.id}/mel"].shape[0]),
                    "takes": len(rec.takes),
                    "shard": rel,
                    "audio": f"audio/{rec.id}.wav",
                    "missing_joints": sorted(rec.missing_joints, key=JOINT_NAMES.index),
                    "missing_face": sorted(rec.missing_face, key=ARKIT_NAMES.index),
                    "metadata": rec.metadata,
                }
            )
        self._pending = []

    def _draw_splits(self) -> dict[str, str]:
        """Each group's split: the one its source prescribes, else drawn among its stratum's groups."""
        fixed: dict[str, str] = {}
        strata: dict[str, set[str]] = {}
        stratum_of: dict[str, str] = {}
        for e in self._entries:
            if e["split"] is not None and fixed.setdefault(e["group"], e["split"]) != e["split"]:
                raise ValueError(f"group {e['group']!r} is given two splits")
            if stratum_of.setdefault(e["group"], e["stratum"]) != e["stratum"]:
                raise ValueError(f"group {e['group']!r} is in two strata")
            strata.setdefault(e["stratum"], set()).add(e["group"])
        splits: dict[str, str] = {}
        for groups in strata.values():
            splits.update(assign_splits(sorted(groups), self.seed, fixed={g: fixed[g] for g in groups & fixed.keys()}))
        return splits

    def close(self) -> Path:
        """Flush the last shard, draw the splits and write the manifest; returns its path."""
        if self._closed:
            return self.folder / MANIFEST
        self._flush()
        if not self._entries:
            raise UserError(f"{self.folder}: no conversations to write")
        splits = self._draw_splits()
        conversations = []
        for e in self._entries:
            e["split"] = splits[e["group"]]
            conversations.append(ConversationInfo(**e).to_json())
        frames = sum(e["frames"] for e in self._entries)
        manifest = {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "fps": FPS,
            "sample_rate": ANALYSIS_RATE,
            "audio_features": self.spec.to_dict(),
            "source": self.source,
            "licence": self.licence,
            "split_seed": self.seed,
            "hours": round(frames / FPS / 3600.0, 6),
            "speakers": sorted({e["speaker"] for e in self._entries}),
            "splits": {s: sum(1 for e in self._entries if e["split"] == s) for s in SPLITS},
            "shards": self._shards,
            "conversations": conversations,
        }
        path = self.folder / MANIFEST
        write_text_atomic(path, json.dumps(manifest, indent=1) + "\n")
        self._closed = True
        return path

    def abort(self) -> None:
        """Remove every file written so far (and the folder, when this writer created it)."""
        for path in self._written:
            path.unlink(missing_ok=True)
        if self._created:
            shutil.rmtree(self.folder, ignore_errors=True)
        else:
            for sub in ("audio", "shards"):
                try:
                    (self.folder / sub).rmdir()
                except OSError:
                    pass
        self._closed = True
