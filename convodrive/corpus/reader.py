"""Reading a corpus: the manifest checked on open, arrays memory-mapped, random windows fast.

``Corpus.open`` checks what is cheap to check for every file (each shard present at its recorded
size, each WAV's length against its motion), so a damaged corpus fails at once with one line
naming the file, not an hour into training; ``check`` also opens every shard and checks every
array. Windows are slices of memory maps: a 180-frame window costs its own bytes, not its shard's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import soundfile as sf

from convodrive import FPS
from convodrive.audio.features import frame_edge
from convodrive.audio.logmel import MelSpec
from convodrive.audio.source import ANALYSIS_RATE, AudioSource, DyadicAudio, motion_frames_for
from convodrive.corpus.manifest import MANIFEST, SPLITS, ConversationInfo, read_manifest
from convodrive.corpus.shards import ShardMap
from convodrive.motion import representation
from convodrive.motion.channels import NUM_BLENDSHAPES
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import NUM_JOINTS
from convodrive.plumbing.errors import InputFileError, UserError

_FIELDS = ("pose", "translation", "face", "vad", "state")


@dataclasses.dataclass(frozen=True)
class Window:
    """``length`` frames of one take of one conversation, from frame ``start``."""

    conversation: str
    take: int
    start: int
    speaker: str
    pose: np.ndarray
    """(L, 55, 3) local axis-angle rotations."""
    translation: np.ndarray
    face: np.ndarray
    vad: np.ndarray
    state: np.ndarray
    mel: np.ndarray
    """(L, 2, bands) log-mel of self (0) and the partner (1), frame-aligned."""
    joint_mask: np.ndarray
    face_mask: np.ndarray

    def features(self) -> np.ndarray:
        """(L, FEATURE_DIM) learning features (``convodrive.motion.representation``)."""
        return representation.encode(self.pose, self.face, self.vad)

    def feature_mask(self) -> np.ndarray:
        """(FEATURE_DIM,) True where the corpus has real data for that feature."""
        return representation.feature_mask(self.joint_mask, self.face_mask)

    def clip(self) -> MotionClip:
        return MotionClip(
            pose=self.pose, translation=self.translation, face=self.face, vad=self.vad, state=self.state, fps=FPS
        )


class Corpus:
    """An opened corpus folder. Open with ``Corpus.open(path)``."""

    def __init__(self, folder: Path, manifest: dict[str, Any], conversations: list[ConversationInfo]) -> None:
        self.folder = folder
        self.manifest = manifest
        self.conversations = conversations
        self._by_id = {c.id: c for c in conversations}
        self._shards: dict[str, ShardMap] = {}
        self.mel_spec = MelSpec.from_dict(manifest.get("audio_features", {}))
        self.speakers: list[str] = sorted({c.speaker for c in conversations})

    @classmethod
    def open(cls, folder: str | Path) -> Corpus:
        folder = Path(folder)
        manifest = read_manifest(folder)
        source = folder / MANIFEST
        conversations = [ConversationInfo.from_json(entry, source) for entry in manifest["conversations"]]
        if not conversations:
            raise InputFileError(source, "lists no conversations")
        if len({c.id for c in conversations}) != len(conversations):
            raise InputFileError(source, "lists a conversation id twice")
        sizes: dict[str, int] = {}
        for shard in manifest["shards"]:
            try:
                sizes[str(shard["path"])] = int(shard["bytes"])
            except (KeyError, TypeError, ValueError):
                raise InputFileError(source, "bad shard entry (needs 'path' and 'bytes')") from None
        for rel, expected in sizes.items():
            path = folder / rel
            if not path.is_file():
                raise InputFileError(
                    path, "shard missing: the corpus manifest lists it but the folder does not hold it"
                )
            actual = path.stat().st_size
            if actual != expected:
                raise InputFileError(path, f"truncated or altered shard: {actual} bytes, the manifest says {expected}")
        for conv in conversations:
            if conv.shard not in sizes:
                raise InputFileError(source, f"conversation {conv.id}: shard {conv.shard} is not in the shard list")
            _check_audio_length(folder / conv.audio, conv.frames)
        return cls(folder, manifest, conversations)

    # -- what it holds ------------------------------------------------------------------------
    @property
    def hours(self) -> float:
        return sum(c.frames for c in self.conversations) / FPS / 3600.0

    def split(self, name: str) -> list[ConversationInfo]:
        if name not in SPLITS:
            raise UserError(f"unknown split {name!r} (choose {', '.join(SPLITS)})")
        return [c for c in self.conversations if c.split == name]

    def conversation(self, conversation_id: str) -> ConversationInfo:
        try:
            return self._by_id[conversation_id]
        except KeyError:
            raise UserError(f"{self.folder}: no conversation {conversation_id!r}") from None

    def speaker_index(self, speaker: str) -> int:
        """A stable integer for a speaker label (its place in the sorted label list)."""
        return self.speakers.index(speaker)

    # -- arrays -------------------------------------------------------------------------------
    def _shard(self, conv: ConversationInfo) -> ShardMap:
        if conv.shard not in self._shards:
            self._shards[conv.shard] = ShardMap(self.folder / conv.shard)
        return self._shards[conv.shard]

    def _array(self, conv: ConversationInfo, field: str) -> np.ndarray:
        return self._shard(conv).array(f"{conv.id}/{field}")

    def window(self, conversation_id: str, take: int, start: int, length: int) -> Window:
        conv = self.conversation(conversation_id)
        if not 0 <= take < conv.takes:
            raise UserError(f"conversation {conv.id} has {conv.takes} takes, not take {take}")
        if not (0 <= start and length >= 0 and start + length <= conv.frames):
            raise UserError(f"window {start}+{length} is outside conversation {conv.id} ({conv.frames} frames)")
        stop = start + length
        arrays = {f: np.array(self._array(conv, f)[take, start:stop]) for f in _FIELDS}
        return Window(
            conversation=conv.id,
            take=take,
            start=start,
            speaker=conv.speaker,
            mel=np.array(self._array(conv, "mel")[start:stop]),
            joint_mask=conv.joint_mask,
            face_mask=conv.face_mask,
            **arrays,
        )

    def sample_windows(self, split: str, length: int, count: int, rng: np.random.Generator) -> list[Window]:
        """``count`` random windows of ``length`` frames from ``split``: conversations drawn in
        proportion to their usable frames, then a random take and start."""
        convs = [c for c in self.split(split) if c.frames >= length]
        if not convs:
            raise UserError(f"{self.folder}: no {split} conversation is {length} frames long")
        weights = np.array([c.frames - length + 1 for c in convs], np.float64)
        picks = rng.choice(len(convs), size=count, p=weights / weights.sum())
        out = []
        for i in picks:
            conv = convs[int(i)]
            out.append(
                self.window(conv.id, int(rng.integers(conv.takes)), int(rng.integers(conv.frames - length + 1)), length)
            )
        return out

    def takes(self, conversation_id: str) -> list[MotionClip]:
        """Every take of a conversation, whole."""
        conv = self.conversation(conversation_id)
        return [self.window(conv.id, k, 0, conv.frames).clip() for k in range(conv.takes)]

    def mel(self, conversation_id: str) -> np.ndarray:
        conv = self.conversation(conversation_id)
        return np.array(self._array(conv, "mel"))

    def audio(self, conversation_id: str) -> DyadicAudio:
        """Both voices of a conversation at 16 kHz (self, partner)."""
        conv = self.conversation(conversation_id)
        return AudioSource(self.folder / conv.audio).read_all()

    def samples(self, conversation_id: str, start: int, length: int) -> np.ndarray:
        """(n, 2) float32 samples at 16 kHz of motion frames ``start .. start+length-1`` (self,
        partner), read from the stored WAV without loading the rest: what a front-end that hears
        raw audio (wav2vec) trains on. Frame k covers samples ``[edge(k), edge(k+1))``."""
        conv = self.conversation(conversation_id)
        if not (0 <= start and length >= 0 and start + length <= conv.frames):
            raise UserError(f"window {start}+{length} is outside conversation {conv.id} ({conv.frames} frames)")
        first, stop = int(frame_edge(start)), int(frame_edge(start + length))
        with sf.SoundFile(self.folder / conv.audio) as fh:
            fh.seek(min(first, fh.frames))
            data = fh.read(stop - first, dtype="float32", always_2d=True)
        if len(data) < stop - first:  # the last frame may reach past the audio's end
            data = np.concatenate([data, np.zeros((stop - first - len(data), 2), np.float32)])
        return data

    def check(self) -> Iterator[ConversationInfo]:
        """Open every shard and check every array of every conversation; yields each one checked."""
        for conv in self.conversations:
            t, k, bands = conv.frames, conv.takes, self.mel_spec.bands
            expected = {
                "pose": (k, t, NUM_JOINTS, 3),
                "translation": (k, t, 3),
                "face": (k, t, NUM_BLENDSHAPES),
                "vad": (k, t, 2),
                "state": (k, t),
                "mel": (t, 2, bands),
            }
            shard = self._shard(conv)
            for field, shape in expected.items():
                array = shard.array(f"{conv.id}/{field}")
                if array.shape != shape:
                    raise InputFileError(
                        shard.path, f"array {conv.id}/{field} has shape {array.shape}, the manifest implies {shape}"
                    )
                if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
                    raise InputFileError(shard.path, f"array {conv.id}/{field} holds NaN or infinite values")
            yield conv


def _check_audio_length(path: Path, frames: int) -> None:
    if not path.is_file():
        raise InputFileError(path, "audio missing: the corpus manifest lists it but the folder does not hold it")
    try:
        info = sf.info(str(path))
    except (sf.LibsndfileError, RuntimeError) as exc:
        raise InputFileError(path, f"not a readable audio file ({str(exc).split(':')[-1].strip()})") from None
    if info.samplerate != ANALYSIS_RATE or info.channels != 2:
        raise InputFileError(path, f"corpus audio must be 16 kHz stereo, got {info.samplerate} Hz, {info.channels} ch")
    have = motion_frames_for(info.frames / ANALYSIS_RATE)
    if have != frames:
        raise InputFileError(
            path, f"audio lasts {info.frames / ANALYSIS_RATE:.3f} s ({have} motion frames) but its motion has {frames}"
        )
