"""Which channel a sound belongs to when each microphone also hears the other person (bleed).

Lapel or desk microphones in one room pick up the other speaker some 10-20 dB down and a few
milliseconds late. A level detector on one channel then hears the partner as self. Deciding from
both channels together fixes that: where the two windows around a frame are coherent (a strong
normalised cross-correlation at a short lag, so one is largely a delayed copy of the other) the
quieter one is the copy, the bleed. The lag settles near-equal levels (badly balanced microphone
gains): a channel whose copy of the other arrives later is the far microphone, so it is the bleed
unless it is clearly the louder one.

Like the other raw features this is a pure function of the samples around each frame, computed
row by row in a batch-independent order, so streaming in any chunk size gives the same decisions.
"""

from __future__ import annotations

import numpy as np

from convodrive.audio.features import (
    ACTIVE_DB,
    FFT_SIZE,
    WINDOW,
    frame_centre,
    row_sum,
    rows_irfft,
    rows_rfft,
    windows,
)

MAX_LAG = 160
"""Largest delay between the microphones considered, samples at 16 kHz (10 ms: 3.4 m of air)."""
COHERENT = 0.5
"""Peak normalised cross-correlation from which one channel is taken to hold a copy of the other."""
DOMINANCE_DB = 3.0
"""How much louder the other channel must be for a coherent frame to count as bleed."""
LATE_LAG = 4
"""A copy this many samples (0.25 ms) late or more was heard by the far microphone."""
LATE_DOMINANCE_DB = -3.0
"""With the lag pointing at it, a channel is the bleed unless it is 3 dB louder than the other."""
_PRE_EMPHASIS = 0.95
_HANN = np.hanning(WINDOW - 1)


def bleed_frames(
    padded_self: np.ndarray, padded_other: np.ndarray, pad_start: int, first: int, count: int, raw_db: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame ``first .. first+count-1``: is self's channel bleed from the other, and the reverse.

    ``raw_db`` (2, count) holds both channels' frame levels; frames where either is below the
    level a voice needs are skipped: a near-silent channel holds no copy worth deciding about, and
    a clean recording (the other channel quiet whenever one speaks) costs next to nothing. Both buffers start at ``pad_start`` and
    reach ``samples_needed(first + count)``, as for ``raw_frames``.
    """
    bleed_self = np.zeros(count, bool)
    bleed_other = np.zeros(count, bool)
    rows = np.flatnonzero(raw_db.min(axis=0) > ACTIVE_DB)
    if not len(rows):
        return bleed_self, bleed_other
    centres = frame_centre(np.arange(first, first + count)[rows]) - pad_start
    starts = centres - WINDOW // 2
    a = _emphasised(windows(padded_self, starts, WINDOW))
    b = _emphasised(windows(padded_other, starts, WINDOW))
    size = FFT_SIZE[a.shape[1] + MAX_LAG]
    spec_a, spec_b = rows_rfft(a, size), rows_rfft(b, size)
    xc = rows_irfft(spec_a * np.conj(spec_b), size)
    # Lag l >= 0: self lags the other by l samples (sum of a[n + l] b[n]); l < 0: the other lags.
    lags = np.concatenate([xc[:, -MAX_LAG:], xc[:, : MAX_LAG + 1]], axis=1)
    energy_a, energy_b = row_sum(a * a), row_sum(b * b)
    peak = np.argmax(np.abs(lags), axis=1)
    rho = np.abs(lags[np.arange(len(rows)), peak]) / np.sqrt(energy_a * energy_b + 1e-20)
    lag = peak - MAX_LAG
    self_over_other = 10.0 * np.log10((energy_a + 1e-12) / (energy_b + 1e-12))
    coherent = rho >= COHERENT
    bleed_self[rows] = coherent & (
        (-self_over_other >= DOMINANCE_DB) | ((lag >= LATE_LAG) & (self_over_other <= -LATE_DOMINANCE_DB))
    )
    bleed_other[rows] = coherent & (
        (self_over_other >= DOMINANCE_DB) | ((lag <= -LATE_LAG) & (-self_over_other <= -LATE_DOMINANCE_DB))
    )
    return bleed_self, bleed_other


def _emphasised(windows: np.ndarray) -> np.ndarray:
    """First-difference pre-emphasis and a Hann taper: whitens speech's steep low-frequency
    spectrum, which sharpens the correlation peak and keeps a voice's own periodicity from
    passing for a copy of the other channel."""
    w = windows.astype(np.float64)
    return (w[:, 1:] - _PRE_EMPHASIS * w[:, :-1]) * _HANN
