"""Streaming per-frame speech features of one voice: loudness, voice activity, F0, accents, syllables.

Frame k of the 30 fps motion clock covers samples ``[edge(k), edge(k+1))`` with
``edge(k) = floor(k * 1600 / 3)``. Three stages, each a pure function of the samples so far, so the
output never depends on how the audio was cut into chunks:

1. *raw* features of frame m (``raw_frames``): frame RMS, and F0 and spectral shape from a
   ``WINDOW``-sample window centred on the frame; they need audio up to ``centre(m) + WINDOW/2``,
   less than 1.5 frames past the frame's start.
2. *tracked* features of frame f (``voice_tracker.VoiceTracker``): voice activity with hysteresis, whether the
   frame itself sounds (above the off threshold, with no hangover: pauses show), the smoothed
   envelope, pitch accents, syllable nuclei and onsets, laughter-like bursts. Peaks are decided
   with ``TRACK_LOOKAHEAD`` (2) raw frames of look-ahead, so frame f is final once raw frame f+2 is.
3. Together: frame f's features need audio up to ``(f + 3.5) / 30`` s, within the 3 frames
   (100 ms) of look-ahead of the audio analysis.
"""

from __future__ import annotations

import math

import numpy as np

from convodrive.audio.source import ANALYSIS_RATE

WINDOW = 1024
"""F0 and spectral window, samples: two periods of a 70 Hz voice."""
SPECTRUM_WINDOW = 256
ACTIVE_DB = -56.0
"""Frames quieter than this (dBFS) cannot hold a voice: F0 and spectrum are skipped there."""
TRACK_LOOKAHEAD = 2
"""Raw frames past frame f that deciding frame f's peaks (accents, nuclei) may look at."""
_F0_MIN, _F0_MAX = 70.0, 400.0


def frame_edge(k: np.ndarray | int) -> np.ndarray | int:
    """First sample of frame k (exact integer arithmetic, so every chunking agrees)."""
    return (np.asarray(k) * 1600) // 3 if isinstance(k, np.ndarray) else (k * 1600) // 3


def frame_centre(k: np.ndarray | int) -> np.ndarray | int:
    return ((np.asarray(k) * 2 + 1) * 800) // 3 if isinstance(k, np.ndarray) else ((2 * k + 1) * 800) // 3


def samples_needed(num_raw_frames: int) -> int:
    """Samples that must have arrived before raw frames ``0 .. num_raw_frames-1`` can be computed."""
    if num_raw_frames <= 0:
        return 0
    last = num_raw_frames - 1
    return max(frame_edge(last + 1), frame_centre(last) + WINDOW // 2)


RAW_FIELDS = ("db", "f0", "periodicity", "centroid", "f1_frac", "f2_frac", "low_frac", "hiss_frac", "bleed")
"""Per raw frame; ``bleed`` (the frame only carries the other voice, see ``audio.bleed``) is set
by the dyadic analysis and False for a voice analysed alone."""


def raw_frames(padded: np.ndarray, pad_start: int, first: int, count: int) -> dict[str, np.ndarray]:
    """Raw features of frames ``first .. first+count-1``.

    ``padded`` holds samples from absolute index ``pad_start`` (which may be negative: zeros before
    the file's start) and must reach ``samples_needed(first + count)``. Vectorised over frames.
    """
    k = np.arange(first, first + count)
    # Loudness: RMS over the frame's own samples.
    starts, lengths = frame_edge(k) - pad_start, frame_edge(k + 1) - frame_edge(k)  # 533 or 534
    sq = np.square(windows(padded, starts, 534), dtype=np.float64)
    # Row sums along the contiguous last axis: the same summation order in every row, however
    # many rows a batch holds (so chunking cannot change the result).
    power = (sq[:, :533].sum(axis=1) + np.where(lengths == 534, sq[:, 533], 0.0)) / lengths
    db = 10.0 * np.log10(power + 1e-10)

    f0 = np.full(count, 100.0)
    best = np.zeros(count)
    centroid, f1, f2, low, hiss = (np.zeros(count) for _ in range(5))
    # The rest only matters where there may be a voice; skipping quiet frames halves the cost.
    rows = np.flatnonzero(db > ACTIVE_DB)
    if len(rows):
        centres = frame_centre(k[rows]) - pad_start
        win16 = windows(padded, centres - WINDOW // 2, WINDOW).astype(np.float64)
        f0[rows], best[rows] = _pitch(win16)
        centroid[rows], f1[rows], f2[rows], low[rows], hiss[rows] = _spectral_shape(win16)
    return {
        "db": db,
        "f0": f0,
        "periodicity": best,
        "centroid": centroid,
        "f1_frac": f1,
        "f2_frac": f2,
        "low_frac": low,
        "hiss_frac": hiss,
        "bleed": np.zeros(count, bool),
    }


def windows(signal: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """(len(starts), length): the ``length`` samples from each start. A plain gather: on the few
    frames of a streaming step, ``sliding_window_view``'s set-up costs four times as much."""
    return signal[np.asarray(starts)[:, None] + np.arange(length)]


def _pitch(win16: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F0 (Hz) and periodicity (peak normalised autocorrelation) of 16 kHz windows, at 8 kHz.

    Pairs of samples are averaged (a crude low-pass, ample for pitch) to halve the work.
    """
    rate = ANALYSIS_RATE // 2
    lag_min, lag_max = int(rate / _F0_MAX), int(math.ceil(rate / _F0_MIN))
    win = 0.5 * (win16[:, 0::2] + win16[:, 1::2])
    n = win.shape[1]
    win = win - row_sum(win)[:, None] / n
    size = FFT_SIZE[n + lag_max + 2]  # a length with small prime factors: 635 took 4x as long
    spec = rows_rfft(win, size)
    acf = rows_irfft(spec.real**2 + spec.imag**2, size)[:, : lag_max + 2]
    # Energy of the overlapping parts at each lag: the whole window less its last (head) or first
    # (tail) ``lag`` samples; only the first and last lag_max + 1 running sums are needed.
    sq = win**2
    total = row_sum(sq)[:, None]
    m = lag_max + 2
    first = np.concatenate([np.zeros((len(win), 1)), np.cumsum(sq[:, : m - 1], axis=1)], axis=1)
    last = np.concatenate([np.zeros((len(win), 1)), np.cumsum(sq[:, : n - m : -1], axis=1)], axis=1)
    e_head = total - last
    e_tail = total - first
    nac = acf / np.sqrt(e_head * e_tail + 1e-12)
    band = nac[:, lag_min : lag_max + 1]
    best = band.max(axis=1)
    # The shortest lag close to the best avoids halving F0 (picking a multiple of the period).
    lag = lag_min + np.argmax(band >= 0.92 * best[:, None], axis=1)
    r = np.arange(len(win))
    y0, y1, y2 = nac[r, lag - 1], nac[r, lag], nac[r, lag + 1]
    denom = y0 - 2 * y1 + y2
    ok = np.abs(denom) > 1e-9
    shift = np.where(ok, 0.5 * (y0 - y2) / np.where(ok, denom, 1.0), 0.0)
    return rate / (lag + np.clip(shift, -0.5, 0.5)), best


class _FastSizes(dict):
    """Smallest FFT length >= n whose prime factors are 2, 3 and 5 (memoised)."""

    def __missing__(self, n: int) -> int:
        m = n
        while True:
            k = m
            for p in (2, 3, 5):
                while k % p == 0:
                    k //= p
            if k == 1:
                self[n] = m
                return m
            m += 1


FFT_SIZE = _FastSizes()
_SPEC_FREQS = np.fft.rfftfreq(SPECTRUM_WINDOW, 1.0 / ANALYSIS_RATE)
_HANN = np.hanning(SPECTRUM_WINDOW)


def _spectral_shape(win16: np.ndarray) -> tuple[np.ndarray, ...]:
    """Centroid and band fractions of the central ``SPECTRUM_WINDOW`` samples: the mouth shape the
    sound suggests (open vowels: F1 band; front vowels: F2 band; rounded: low band; hiss)."""
    half = (WINDOW - SPECTRUM_WINDOW) // 2
    mag = np.abs(rows_rfft(win16[:, half : half + SPECTRUM_WINDOW] * _HANN, SPECTRUM_WINDOW)) ** 2
    f = _SPEC_FREQS
    # Band sums as differences of a running sum along each row: the same arithmetic in every row
    # whatever the batch's shape (a plain sum may change its order with the shape).
    c = np.concatenate([np.zeros((len(mag), 1)), np.cumsum(mag, axis=1)], axis=1)

    def band(lo: float, hi: float) -> np.ndarray:
        return c[:, np.searchsorted(f, hi)] - c[:, np.searchsorted(f, lo)]

    total = band(80, 1e9) + 1e-12
    speech = band(200, 3000) + 1e-12

    def frac(lo: float, hi: float, ref: np.ndarray) -> np.ndarray:
        return band(lo, hi) / ref

    centroid = row_sum(mag * f) / (c[:, -1] + 1e-12)
    return centroid, frac(550, 1100, speech), frac(1600, 3000, speech), frac(200, 550, speech), frac(3500, 8000, total)


def row_sum(x: np.ndarray) -> np.ndarray:
    """Sum along each row, in an order that does not depend on the number of rows (see
    ``_spectral_shape``): each C-contiguous row is reduced on its own by the same pairwise loop."""
    return np.add.reduce(np.ascontiguousarray(x), axis=1)


def rows_irfft(x: np.ndarray, n: int) -> np.ndarray:
    rows = len(x)
    padded = np.zeros((-(-rows // 8) * 8, x.shape[1]), complex)
    padded[:rows] = x
    return np.fft.irfft(padded, n=n, axis=1)[:rows]


def rows_rfft(x: np.ndarray, n: int) -> np.ndarray:
    """Row-wise rfft, padded to a multiple of 8 rows so every row takes the same SIMD code path
    (the FFT rounds a row differently in a full vector lane than in the remainder), which keeps
    results bit-identical however many frames a batch holds."""
    rows = len(x)
    padded = np.zeros((-(-rows // 8) * 8, x.shape[1]))
    padded[:rows] = x
    return np.fft.rfft(padded, n=n, axis=1)[:rows]
