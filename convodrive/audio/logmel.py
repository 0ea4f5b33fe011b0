"""Log-mel features at the motion frame rate: what the learned models hear, in training and at run time.

One implementation serves both: the corpus stores these features and a learned generator computes
them on live audio with ``LogMelStream``, which gives the same numbers bit for bit whatever the
chunk sizes (each frame is a pure function of its own window, computed row by row; see
``tests/audio/test_logmel.py``), so a model never hears at run time what it did not hear in training.

Frame k of the 30 fps motion clock (samples ``[edge(k), edge(k+1))`` at 16 kHz, as in
``convodrive.audio.features``) gets one vector of ``bands`` log-mel energies from a Hann window of
``window`` samples centred on the frame's centre. Receptive field: ``window`` samples (50 ms by
default). Look-ahead: frame k is final once audio up to ``edge(k+1) + lookahead_samples`` has
arrived (134 samples, 8.4 ms, by default), i.e. a model that reads frames up to k waits for
``(k+1)/30 s + 8.4 ms`` of audio. Before the start and after ``finish`` the signal is zero.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from convodrive.audio.features import frame_centre, frame_edge
from convodrive.audio.source import ANALYSIS_RATE, DyadicAudio, motion_frames_for

_BLOCK_FRAMES = 1024
"""Frames computed per vectorised step: bounds memory on hour-long audio."""


@dataclasses.dataclass(frozen=True)
class MelSpec:
    """The feature definition; a model folder stores ``to_dict`` so its runtime computes the same."""

    bands: int = 80
    window: int = 800
    """Samples at 16 kHz (50 ms), Hann, centred on the frame's centre; even."""
    n_fft: int = 1024
    fmin: float = 60.0
    fmax: float = 7600.0
    floor: float = 1e-10
    """Energies below this are clamped before the (natural) log."""

    def __post_init__(self) -> None:
        if self.window % 2 or not 0 < self.window <= self.n_fft:
            raise ValueError(f"mel window must be even and at most n_fft ({self.n_fft}), got {self.window}")
        if not 0 <= self.fmin < self.fmax <= ANALYSIS_RATE / 2 or self.bands < 1:
            raise ValueError(f"bad mel bands: {self.bands} between {self.fmin} and {self.fmax} Hz")

    @property
    def lookahead_samples(self) -> int:
        """Samples past the end of frame k that frame k's window reaches (the pattern repeats every 3 frames)."""
        return max(int(frame_centre(k)) + self.window // 2 - int(frame_edge(k + 1)) for k in range(3))

    def samples_needed(self, num_frames: int) -> int:
        """Audio samples that must have arrived before frames ``0 .. num_frames-1`` are final."""
        return 0 if num_frames <= 0 else int(frame_centre(num_frames - 1)) + self.window // 2

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "log-mel", "sample_rate": ANALYSIS_RATE, "fps": 30, **dataclasses.asdict(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MelSpec:
        fields = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in fields})


DEFAULT_SPEC = MelSpec()


def _hz_to_mel(hz: np.ndarray) -> np.ndarray:
    return 2595.0 * np.log10(1.0 + hz / 700.0)


def _mel_to_hz(mel: np.ndarray) -> np.ndarray:
    return 700.0 * (10.0 ** (mel / 2595.0) - 1.0)


def _band_edges(spec: MelSpec) -> np.ndarray:
    """(bands + 2,) Hz: band m rises from edge m, peaks at m + 1 and falls to m + 2."""
    return np.asarray(
        _mel_to_hz(np.linspace(_hz_to_mel(np.array(spec.fmin)), _hz_to_mel(np.array(spec.fmax)), spec.bands + 2))
    )


class _Filterbank:
    """Triangular mel filters (HTK scale, peak 1) applied as a sparse sum, row by row.

    A dense matmul would hand rows to BLAS, whose summation order may depend on how many rows a
    call holds; the sparse gather and ``reduceat`` sum each row the same way whatever the batch.
    """

    def __init__(self, spec: MelSpec) -> None:
        bins = np.arange(spec.n_fft // 2 + 1) * ANALYSIS_RATE / spec.n_fft
        edges = _band_edges(spec)
        index: list[np.ndarray] = []
        weight: list[np.ndarray] = []
        starts: list[int] = []
        for m in range(spec.bands):
            lo, mid, hi = edges[m], edges[m + 1], edges[m + 2]
            w = np.minimum((bins - lo) / (mid - lo), (hi - bins) / (hi - mid))
            support = np.flatnonzero(w > 0)
            if len(support) == 0:  # a band narrower than a bin: take the nearest bin
                support = np.array([int(np.argmin(np.abs(bins - mid)))])
                w = np.ones_like(bins)
            starts.append(sum(len(i) for i in index))
            index.append(support)
            weight.append(w[support])
        self.index = np.concatenate(index)
        self.weight = np.concatenate(weight)
        self.starts = np.array(starts)

    def __call__(self, power: np.ndarray) -> np.ndarray:
        return np.add.reduceat(power[:, self.index] * self.weight, self.starts, axis=1)


class LogMelStream:
    """Log-mel frames of ``channels`` signals as their audio arrives, in chunks of any size."""

    def __init__(self, channels: int = 2, spec: MelSpec = DEFAULT_SPEC) -> None:
        self.spec = spec
        self.channels = channels
        self._filters = _Filterbank(spec)
        self._window = np.hanning(spec.window + 1)[:-1]  # periodic Hann
        half = spec.window // 2
        self._buf_start = -half  # absolute index of the buffer's first sample; zeros before 0
        self._buf = np.zeros((half, channels), np.float64)
        self._received = 0
        self._done = 0
        self._finished = False

    @property
    def frames_done(self) -> int:
        return self._done

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Append (n, channels) samples (or (n,) for one channel); return the frames now final,
        (k, channels, bands) float32."""
        if self._finished:
            raise RuntimeError("LogMelStream.push after finish")
        self._append(samples)
        ready = self._done
        while self.spec.samples_needed(ready + 1) <= self._received:
            ready += 1
        return self._compute(ready)

    def finish(self, num_frames: int) -> np.ndarray:
        """Pad with silence and return the frames up to ``num_frames`` not yet returned."""
        need = self.spec.samples_needed(num_frames)
        if need > self._received:
            self._append(np.zeros((need - self._received, self.channels), np.float64))
        self._finished = True
        return self._compute(max(num_frames, self._done))

    def _append(self, samples: np.ndarray) -> None:
        x = np.asarray(samples, np.float64)
        x = x.reshape(-1, 1) if x.ndim == 1 else x
        if x.shape[1] != self.channels:
            raise ValueError(f"expected {self.channels} channels, got {x.shape[1]}")
        self._buf = np.concatenate([self._buf, x])
        self._received += len(x)

    def _compute(self, stop: int) -> np.ndarray:
        spec = self.spec
        out = np.empty((max(stop - self._done, 0), self.channels, spec.bands), np.float32)
        offsets = np.arange(spec.window)
        for first in range(self._done, stop, _BLOCK_FRAMES):
            ks = np.arange(first, min(first + _BLOCK_FRAMES, stop))
            starts = np.asarray(frame_centre(ks)) - spec.window // 2 - self._buf_start
            for c in range(self.channels):
                frames = self._buf[starts[:, None] + offsets, c] * self._window
                power = np.abs(np.fft.rfft(frames, n=spec.n_fft, axis=1)) ** 2
                out[ks - self._done, c] = np.log(np.maximum(self._filters(power), spec.floor))
        self._done = max(self._done, stop)
        keep_from = int(frame_centre(self._done)) - spec.window // 2
        drop = keep_from - self._buf_start
        if drop > 0:
            self._buf = self._buf[drop:]
            self._buf_start = keep_from
        return out


def log_mel(samples: np.ndarray, num_frames: int | None = None, spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """Offline: (T, channels, bands) for (n, channels) or (n,) samples at 16 kHz; T defaults to
    the motion frames that cover the audio (``motion_frames_for``)."""
    x = np.asarray(samples)
    channels = 1 if x.ndim == 1 else x.shape[1]
    stream = LogMelStream(channels, spec)
    head = stream.push(x)
    total = motion_frames_for(len(x) / ANALYSIS_RATE) if num_frames is None else num_frames
    if len(head) > total:
        return head[:total]
    return np.concatenate([head, stream.finish(total)])


def dyadic_log_mel(audio: DyadicAudio, num_frames: int | None = None, spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """(T, 2, bands): self on index 0, the partner on 1, frame-aligned with the motion clock."""
    return log_mel(np.stack([audio.self_voice, audio.other_voice], axis=1), num_frames or audio.num_frames, spec)


def band_centres(spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """(bands,) each band's peak frequency in Hz."""
    return _band_edges(spec)[1:-1]


def band_average(spec: MelSpec, power_of_hz: np.ndarray) -> np.ndarray:
    """(bands,) a power response given at the FFT's ``n_fft // 2 + 1`` bin frequencies, averaged
    over each band's triangle: what the band's energy is multiplied by for a signal flat in the band."""
    filters = _Filterbank(spec)
    flat = filters(np.ones((1, len(power_of_hz))))[0]
    return np.asarray(filters(np.asarray(power_of_hz, np.float64)[None])[0] / flat)
