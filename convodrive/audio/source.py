"""Dyadic audio input: WAV, FLAC, OGG, MP3 (libsndfile) and M4A/AAC (ffmpeg), read in chunks.

Channel 0 is self, channel 1 the partner; a mono file means the partner is silent; a file with
more channels needs an explicit choice. Files are read block by block through a streaming
polyphase resampler (``resample``), so a two-hour file runs in constant memory and the chunks join
seamlessly (they equal resampling the whole file at once).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import soundfile as sf

from convodrive import FPS
from convodrive.audio import ffmpeg
from convodrive.audio.resample import StreamResampler
from convodrive.plumbing.errors import InputFileError, os_reason

ANALYSIS_RATE = 16_000
"""Every generator sees audio at 16 kHz: enough for speech, and what pocketsphinx expects."""
CHUNK_SAMPLES = 1_600
"""100 ms chunks: exactly 3 motion frames at 30 fps."""
SUPPORTED_FORMATS = {"WAV", "WAVEX", "RF64", "W64", "FLAC", "OGG", "AIFF", "MP3"}
"""libsndfile's formats that convodrive reads; M4A and AAC go through ffmpeg (``audio.ffmpeg``)."""
READABLE = "WAV, FLAC, OGG, MP3 and M4A/AAC"
SUPPORTED_EXTENSIONS = {".wav", ".rf64", ".w64", ".flac", ".ogg", ".oga", ".aiff", ".aif", ".mp3", ".m4a", ".aac"}
"""File names that say "audio file" (where an argument may also name a device)."""
_BLOCK_SECONDS = 0.5
"""Read granularity: a file that fails part-way loses at most this much before the failure."""


@dataclasses.dataclass(frozen=True)
class ChannelMap:
    """Which file channels are self and the partner; ``other`` None means a silent partner."""

    self_channel: int = 0
    other_channel: int | None = 1

    @classmethod
    def parse(cls, text: str) -> ChannelMap:
        """Parse the CLI form ``SELF,OTHER`` (``OTHER`` may be ``-`` for a silent partner)."""
        parts = [p.strip() for p in text.split(",")]
        try:
            if len(parts) == 1:
                return cls(int(parts[0]), None)
            if len(parts) == 2:
                return cls(int(parts[0]), None if parts[1] in ("-", "") else int(parts[1]))
        except ValueError:
            pass
        raise ValueError(f"--channels expects SELF,OTHER channel numbers such as 0,1, got {text!r}")


@dataclasses.dataclass(frozen=True)
class AudioChunk:
    """A stretch of both voices at ``ANALYSIS_RATE``. ``start`` counts samples from the file's start."""

    start: int
    self_voice: np.ndarray
    other_voice: np.ndarray
    final: bool = False

    @property
    def time(self) -> float:
        return self.start / ANALYSIS_RATE

    def __len__(self) -> int:
        return len(self.self_voice)


@dataclasses.dataclass(frozen=True)
class DyadicAudio:
    """Both voices of a conversation held in memory at ``ANALYSIS_RATE`` (offline use, tests)."""

    self_voice: np.ndarray
    other_voice: np.ndarray
    source: str = ""

    @property
    def duration(self) -> float:
        return len(self.self_voice) / ANALYSIS_RATE

    @property
    def num_frames(self) -> int:
        return motion_frames_for(self.duration)

    def chunks(self, chunk_samples: int = CHUNK_SAMPLES) -> Iterator[AudioChunk]:
        n = len(self.self_voice)
        for start in range(0, max(n, 1), chunk_samples):
            stop = min(start + chunk_samples, n)
            yield AudioChunk(start, self.self_voice[start:stop], self.other_voice[start:stop], final=stop >= n)


def motion_frames_for(duration: float) -> int:
    """The number of 30 fps frames that cover ``duration`` seconds of audio."""
    return max(1, int(round(duration * FPS)))


@dataclasses.dataclass(frozen=True)
class AudioInfo:
    path: Path
    sample_rate: int
    channels: int
    frames: int
    format: str
    subtype: str
    exact_frames: bool = True
    """False where the file only estimates its length (raw AAC): reading stops where decoding does."""

    @property
    def decoder(self) -> str:
        return "ffmpeg" if self.format in ffmpeg.CONTAINERS.values() else "libsndfile"

    @property
    def duration(self) -> float:
        return self.frames / self.sample_rate

    @property
    def num_motion_frames(self) -> int:
        return motion_frames_for(self.duration)


class AudioSource:
    """An audio file opened for dyadic, chunked reading. Opening validates the whole file."""

    def __init__(self, path: str | Path, channel_map: ChannelMap | None = None) -> None:
        self.path = Path(path)
        self.info = probe_audio(self.path)
        self.channel_map = _resolve_channels(self.info, channel_map)
        if self.info.subtype.startswith(("FLOAT", "DOUBLE")) or self.info.format == "OGG":
            self._check_finite()

    def _check_finite(self) -> None:
        with sf.SoundFile(self.path) as fh:
            blocks = fh.blocks(blocksize=int(_BLOCK_SECONDS * fh.samplerate), dtype="float32", always_2d=True)
            with self._decoding(lambda: fh.tell()):
                for block in blocks:
                    if not np.all(np.isfinite(block)):
                        raise InputFileError(self.path, "audio holds NaN or infinite samples")

    @contextlib.contextmanager
    def _decoding(self, position: Callable[[], int]) -> Iterator[None]:
        """Turn a decoder failure (corrupt or truncated data) into an ``AudioDecodeError``."""
        try:
            yield
        except (sf.LibsndfileError, RuntimeError) as exc:
            try:
                seconds = position() / self.info.sample_rate
            except Exception:  # the file handle may be unusable after the failure
                seconds = 0.0
            detail = str(exc).split(":")[-1].strip().rstrip(".") or exc.__class__.__name__
            raise AudioDecodeError(self.path, seconds, detail) from None

    def describe(self) -> dict[str, Any]:
        """What the run report says of the audio."""
        return {
            "path": str(self.path),
            "sample_rate": self.info.sample_rate,
            "channels": self.info.channels,
            "duration_s": round(self.duration, 3),
            "self_channel": self.channel_map.self_channel,
            "other_channel": self.channel_map.other_channel,
        }

    def _open(self, cols: list[int]) -> _Reader:
        if self.info.decoder == "ffmpeg":
            limit = self.info.frames if self.info.exact_frames else None
            reader = ffmpeg.FfmpegReader(self.path, self.info.channels, limit, self.info.sample_rate)
            return _Columns(reader, cols)
        return _Columns(_SoundfileReader(self.path), cols)

    @property
    def duration(self) -> float:
        return self.info.duration

    def chunks(self, chunk_samples: int = CHUNK_SAMPLES) -> Iterator[AudioChunk]:
        """Yield chunks of ``chunk_samples`` at ``ANALYSIS_RATE``; the last may be shorter."""
        pending_self = np.zeros(0, np.float32)
        pending_other = np.zeros(0, np.float32)
        start = 0
        for self_block, other_block, last in self._resampled_blocks():
            pending_self = np.concatenate([pending_self, self_block])
            pending_other = np.concatenate([pending_other, other_block])
            while len(pending_self) >= chunk_samples and not (last and len(pending_self) == chunk_samples):
                yield AudioChunk(start, pending_self[:chunk_samples], pending_other[:chunk_samples])
                pending_self, pending_other = pending_self[chunk_samples:], pending_other[chunk_samples:]
                start += chunk_samples
            if last:
                yield AudioChunk(start, pending_self, pending_other, final=True)

    def read_all(self) -> DyadicAudio:
        """The whole file in memory at ``ANALYSIS_RATE``; offline tools and tests use this."""
        parts = list(self.chunks(chunk_samples=ANALYSIS_RATE * 10))
        return DyadicAudio(
            np.concatenate([c.self_voice for c in parts]).astype(np.float32),
            np.concatenate([c.other_voice for c in parts]).astype(np.float32),
            source=str(self.path),
        )

    def _resampled_blocks(self) -> Iterator[tuple[np.ndarray, np.ndarray, bool]]:
        """Read block by block through a streaming resampler (its output equals resampling the
        whole file at once). The end is where the reader runs dry, so a decoder that only
        estimated the length still ends cleanly. Each block is handed on before the next is read,
        so a file that stops decoding part-way still yields what came before the failing block."""
        cols = [self.channel_map.self_channel] + (
            [self.channel_map.other_channel] if self.channel_map.other_channel is not None else []
        )
        resampler = StreamResampler(self.info.sample_rate, ANALYSIS_RATE, channels=len(cols))
        block = max(1, int(_BLOCK_SECONDS * self.info.sample_rate))
        decoded = 0  # native samples handed out so far, for the position of a decoding error
        with self._open(cols) as reader, self._decoding(lambda: decoded):
            while True:
                data = reader.read(block)
                last = len(data) < block
                out = resampler.push(data)
                if last:
                    out = np.concatenate([out, resampler.finish(flat=False)])
                decoded += len(data)
                yield out[:, 0], (out[:, 1] if out.shape[1] > 1 else np.zeros(len(out), np.float32)), last
                if last:
                    return


class _Reader(Protocol):
    def read(self, n: int) -> np.ndarray:
        """Up to ``n`` frames, (m, channels) float32; fewer only at the end."""

    def close(self) -> None: ...


class _SoundfileReader:
    def __init__(self, path: Path) -> None:
        self._fh = sf.SoundFile(path)

    def read(self, n: int) -> np.ndarray:
        return self._fh.read(n, dtype="float32", always_2d=True)

    def close(self) -> None:
        self._fh.close()


class _Columns:
    """A reader that keeps the chosen channels, in order (self first), as a context manager."""

    def __init__(self, reader: _Reader, cols: list[int]) -> None:
        self._reader, self._cols = reader, cols

    def read(self, n: int) -> np.ndarray:
        return np.ascontiguousarray(self._reader.read(n)[:, self._cols])

    def __enter__(self) -> _Columns:
        return self

    def __exit__(self, *exc: object) -> None:
        self._reader.close()


class AudioDecodeError(InputFileError):
    """The audio stopped decoding part-way (corrupt or truncated data): the run ends there."""

    def __init__(self, path: object, seconds: float, detail: str) -> None:
        self.seconds = seconds
        super().__init__(path, f"the audio cannot be decoded after {seconds:.2f} s ({detail})")


class SilentSource:
    """Silence of a given length, read like an ``AudioSource``: the clock of a run with no audio
    file, such as ``convodrive render`` of saved motion without ``--audio``."""

    def __init__(self, duration: float) -> None:
        if not duration > 0:
            raise ValueError(f"silence must last a positive time, got {duration}")
        self.duration = float(duration)
        self.num_samples = max(1, int(round(self.duration * ANALYSIS_RATE)))

    def chunks(self, chunk_samples: int = CHUNK_SAMPLES) -> Iterator[AudioChunk]:
        silence = np.zeros(chunk_samples, np.float32)
        for start in range(0, self.num_samples, chunk_samples):
            stop = min(start + chunk_samples, self.num_samples)
            part = silence[: stop - start]
            yield AudioChunk(start, part, part, final=stop >= self.num_samples)

    def describe(self) -> dict[str, Any]:
        return {"path": None, "silence": True, "duration_s": round(self.duration, 3)}


def probe_audio(path: str | Path) -> AudioInfo:
    """Check that ``path`` is a readable, non-empty audio file of a supported format."""
    path = Path(path)
    try:
        with path.open("rb") as f:  # libsndfile would only say "System error."
            empty = not f.read(1)
    except FileNotFoundError:
        raise InputFileError(path, "no such file") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a folder, not an audio file") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({os_reason(exc)})") from None
    if empty:
        raise InputFileError(path, "file is empty")
    try:
        info = sf.info(str(path))
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        found = ffmpeg.probe(path)
        if found is None:
            detail = str(exc).split(":")[-1].strip() or "unreadable"
            raise InputFileError(path, f"not a readable audio file ({detail})") from None
        result = AudioInfo(
            path, found.sample_rate, found.channels, found.frames, found.format, found.codec, found.exact
        )
    else:
        if info.format not in SUPPORTED_FORMATS:
            raise InputFileError(path, f"unsupported audio format {info.format} (convodrive reads {READABLE})")
        result = AudioInfo(path, int(info.samplerate), int(info.channels), int(info.frames), info.format, info.subtype)
    if result.frames <= 0:
        raise InputFileError(path, "audio holds no samples")
    if result.sample_rate <= 0:
        raise InputFileError(path, f"invalid sample rate {result.sample_rate}")
    if result.channels <= 0:
        raise InputFileError(path, "audio holds no channels")
    return result


def _resolve_channels(info: AudioInfo, channel_map: ChannelMap | None) -> ChannelMap:
    if channel_map is None:
        if info.channels == 1:
            return ChannelMap(0, None)
        if info.channels == 2:
            return ChannelMap(0, 1)
        raise InputFileError(
            info.path,
            f"has {info.channels} channels; choose self and partner with --channels SELF,OTHER (e.g. --channels 0,1)",
        )
    for ch in (channel_map.self_channel, channel_map.other_channel):
        if ch is not None and not 0 <= ch < info.channels:
            raise InputFileError(info.path, f"has no channel {ch} (it has {info.channels}: 0 to {info.channels - 1})")
    return channel_map
