"""Speech the user has, for ``convodrive corpus make``: recorded voices and recorded conversations.

Two kinds of source folder, each with a ``source.json`` naming its licence (``{"licence": "CC-BY-4.0",
"language": "en"}``; ``name`` defaults to the folder's name, ``language`` to ``und``):

- **voices**: one sub-folder per speaker of single-voice utterances (WAV or FLAC, any rate). Two
  speakers are paired into a dialogue by the espeak-ng path's timeline (``dialogues.converse``):
  the same turn taking, pauses, backchannels (a speaker's utterances under ``BACKCHANNEL_SECONDS``)
  and overlaps.
- **conversations**: two-channel recordings (self on channel 0, the partner on 1), taken as they
  are. Their turns come from a segments file beside each (``NAME.json`` or ``NAME.txt``, the format
  of ``eval.segments``, which the CLI reads) or, without one, from their own voice activity
  (``audio.analysis``, which tells bleed from speech using both channels).

The manifest names each source's licence and hours; the files' paths stay on this machine.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import soundfile as sf

from convodrive import FPS
from convodrive.audio.analysis import voice_activity
from convodrive.audio.source import AudioSource, DyadicAudio
from convodrive.audio.synth import trim_silence
from convodrive.plumbing.errors import InputFileError

AUDIO_SUFFIXES = (".wav", ".flac")
SOURCE_FILE = "source.json"
BACKCHANNEL_SECONDS = 1.0
"""Utterances shorter than this serve as a speaker's backchannels (``yeah``, ``mm-hm``)."""


@dataclasses.dataclass(frozen=True)
class SourceInfo:
    """Where recordings came from, as the manifest and the model card name them."""

    name: str
    kind: str
    """``voices`` or ``conversations``."""
    licence: str
    language: str

    def to_json(self, seconds: float) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "licence": self.licence,
            "language": self.language,
            "hours": round(seconds / 3600.0, 4),
        }


def read_source(folder: Path, kind: str) -> SourceInfo:
    """A source folder's ``source.json``; a missing folder or licence is one clear error."""
    if not folder.is_dir():
        raise InputFileError(folder, "no such folder of recordings" if not folder.exists() else "is not a folder")
    path = folder / SOURCE_FILE
    if not path.is_file():
        raise InputFileError(
            folder, f'no {SOURCE_FILE}: write one naming the recordings\' licence, {{"licence": "..."}}'
        )
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(path, f"not readable JSON ({exc.__class__.__name__})") from None
    if not isinstance(data, dict) or not isinstance(data.get("licence"), str) or not data["licence"].strip():
        raise InputFileError(path, 'needs a "licence" text (the terms the recordings may be used under)')
    return SourceInfo(
        str(data.get("name") or folder.name), kind, data["licence"].strip(), str(data.get("language") or "und")
    )


def _audio_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in AUDIO_SUFFIXES)


@dataclasses.dataclass(frozen=True)
class RecordedSpeaker:
    """One speaker's utterances (paths and their lengths in seconds)."""

    name: str
    source: SourceInfo
    files: tuple[Path, ...]
    seconds: tuple[float, ...]

    @property
    def total(self) -> float:
        return float(sum(self.seconds))


def scan_voices(folder: Path) -> list[RecordedSpeaker]:
    """The speakers of a voices folder (each sub-folder with audio), sorted by name."""
    source = read_source(folder, "voices")
    speakers = []
    for sub in sorted(p for p in folder.iterdir() if p.is_dir()):
        infos = [(f, _info(f)) for f in _audio_files(sub)]
        infos = [(f, i) for f, i in infos if i.frames > 0]  # packages hold empty prompts: skipped
        if infos:
            files = [f for f, _ in infos]
            lengths = tuple(i.frames / i.samplerate for _, i in infos)
            speakers.append(RecordedSpeaker(f"{source.name}/{sub.name}", source, tuple(files), lengths))
    if not speakers:
        raise InputFileError(folder, "holds no speaker folder with WAV or FLAC utterances")
    return speakers


def _info(path: Path) -> Any:
    try:
        return sf.info(str(path))
    except RuntimeError as exc:
        raise InputFileError(path, f"not readable audio ({exc})") from None


def load_utterance(path: Path) -> np.ndarray:
    """An utterance as float32 mono at 16 kHz, leading and trailing silence trimmed."""
    return trim_silence(AudioSource(path).read_all().self_voice)


@dataclasses.dataclass(frozen=True)
class RecordedVoice:
    """A recorded speaker as a source of utterances for ``dialogues.converse``: sentences are
    their longer utterances, backchannels their short ones (none when they have none)."""

    speaker: RecordedSpeaker
    amplitude: float

    def pick(self, kind: str, rng: np.random.Generator) -> Path | None:
        short = np.asarray(self.speaker.seconds) < BACKCHANNEL_SECONDS
        pool = np.flatnonzero(short if kind == "backchannel" else ~short)
        if kind != "backchannel" and not len(pool):
            pool = np.arange(len(self.speaker.files))
        return self.speaker.files[int(rng.choice(pool))] if len(pool) else None

    def render(self, item: Path | None, rng: np.random.Generator) -> np.ndarray:
        return load_utterance(item) if item is not None else np.zeros(0, np.float32)


@dataclasses.dataclass(frozen=True)
class RecordedConversation:
    """A two-channel recording to take as it is; ``turns`` from its segments file, if it has one
    (the CLI reads it with ``eval.segments``, a layer above the corpus)."""

    path: Path
    source: SourceInfo
    seconds: float
    turns: dict[str, list[list[float]]] | None = None


def scan_conversations(folder: Path) -> list[RecordedConversation]:
    """A conversations folder's two-channel recordings (a mono or many-channel file is refused)."""
    source = read_source(folder, "conversations")
    files = _audio_files(folder)
    if not files:
        raise InputFileError(folder, "holds no WAV or FLAC conversation")
    found = []
    for path in files:
        info = AudioSource(path).info
        if info.channels != 2:
            raise InputFileError(
                path, f"a recorded conversation needs two channels (self, partner), it has {info.channels}"
            )
        found.append(RecordedConversation(path, source, info.frames / info.sample_rate))
    return found


def segments_beside(path: Path) -> Path | None:
    """The segments file of a recorded conversation: ``NAME.json`` or ``NAME.txt`` beside it."""
    return next((p for p in (path.with_suffix(".json"), path.with_suffix(".txt")) if p.is_file()), None)


def recorded_turns(conv: RecordedConversation, audio: DyadicAudio) -> tuple[dict[str, list[list[float]]], str]:
    """Speech segments per channel (seconds) and where they came from: the segments file, else
    the recording's own voice activity."""
    if conv.turns is not None:
        return conv.turns, "segments file"
    vad = voice_activity(audio) > 0.5
    return {"self": _runs(vad[:, 0]), "partner": _runs(vad[:, 1])}, "voice activity"


def _runs(active: np.ndarray) -> list[list[float]]:
    """Runs of true frames as [start, end] seconds."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], active.astype(np.int8), [0]])))
    return [[round(a / FPS, 2), round(b / FPS, 2)] for a, b in zip(edges[::2], edges[1::2])]


def read_conversation(path: Path) -> DyadicAudio:
    """Both channels of a recorded conversation at 16 kHz (self on channel 0)."""
    return AudioSource(path).read_all()
