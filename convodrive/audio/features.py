"""Streaming per-frame speech features of one voice: loudness, voice activity, F0, accents, syllables.

Frame k of the 30 fps motion clock covers samples ``[edge(k), edge(k+1))`` with
``edge(k) = floor(k * 1600 / 3)``. Three stages, each a pure function of the samples so far, so the
output never depends on how the audio was cut into chunks:

1. *raw* features of frame m (``raw_frames``): frame RMS, and F0 and spectral shape from a
   ``WINDOW``-sample window centred on the frame; they need audio up to ``centre(m) + WINDOW/2``,
   less than 1.5 frames past the frame's start.
2. *tracked* features of frame f (``VoiceTracker``): voice activity with hysteresis, whether the
   frame itself sounds (above the off threshold, with no hangover: pauses show), the smoothed
   envelope, pitch accents, syllable nuclei and onsets, laughter-like bursts. Peaks are decided
   with ``TRACK_LOOKAHEAD`` (2) raw frames of look-ahead, so frame f is final once raw frame f+2 is.
3. Together: frame f's features need audio up to ``(f + 3.5) / 30`` s, within the 3 frames
   (100 ms) of look-ahead of the audio analysis.
"""

from __future__ import annotations

import dataclasses
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
_HISTORY = 48
_BLEED_RELEASE = 3
"""Consecutive bleed frames (the other voice alone in this microphone) that end this voice's turn."""
"""Raw frames of history the tracker keeps (laughter looks back 1 s)."""


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


@dataclasses.dataclass
class VoiceParams:
    """Thresholds of the voice tracker; dBFS of frame RMS. The VAD thresholds are minimums: in
    noise they rise with the tracked noise floor (on at floor + 14 dB, off at floor + 8 dB)."""

    vad_on_db: float = -40.0
    vad_off_db: float = -48.0
    vad_hangover: int = 8
    """Frames below ``vad_off_db`` before the voice counts as stopped (about 250 ms)."""
    voicing: float = 0.55
    accent_st: float = 1.0
    """Semitones above the running pitch baseline that make a local F0 peak a pitch accent."""


TRACK_FIELDS = (
    "db",
    "env",
    "vad",
    "voiced",
    "f0",
    "pitch_st",
    "accent",
    "nucleus",
    "stress",
    "onset",
    "laugh",
    "centroid",
    "f1_frac",
    "f2_frac",
    "low_frac",
    "hiss_frac",
    "bleed",
    "sounding",
)


def _fill_holes(flags: np.ndarray, width: int) -> np.ndarray:
    """``flags`` with gaps of up to ``width`` frames between flagged frames filled: a quiet frame
    inside the other voice's bleed is not this voice speaking."""
    out = flags.copy()
    n = len(flags)
    for gap in range(1, width + 1):
        for shift in range(gap):  # frame i lies ``shift + 1`` frames after a flag, gap - shift before one
            before = np.zeros(n, bool)
            after = np.zeros(n, bool)
            before[shift + 1 :] = flags[: n - shift - 1]
            after[: n - (gap - shift)] = flags[gap - shift :]
            out |= before & after
    return out


class VoiceTracker:
    """Stateful per-voice tracking over raw frames: the decisions that need history or look-ahead.

    ``push(raw)`` appends raw frames and returns the tracked features of every frame that became
    final (those with ``TRACK_LOOKAHEAD`` raw frames after them). At the end of the audio the
    caller pads with silence (``DyadicAnalyzer.finish``).
    """

    def __init__(self, params: VoiceParams | None = None) -> None:
        self.p = params or VoiceParams()
        self._raw = {name: np.zeros(0) for name in RAW_FIELDS}
        self._offset = 0  # absolute index of self._raw[...][0]
        self._next = 0  # next frame to finalise
        self._vad = False
        self._below = 0
        self._bleed_run = 0
        self._baseline = float("nan")
        self._since_accent = 99
        self._since_nucleus = 99
        self._nuclei: list[tuple[int, float, float]] = []
        self._laugh = 0.0
        self._env_mean = 0.3
        self._floor: float | None = None  # noise floor, dBFS
        self._level = -22.0  # running level of this voice's voiced frames, dBFS

    def push(self, raw: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        for name in RAW_FIELDS:
            self._raw[name] = np.concatenate([self._raw[name], raw[name]])
        end = self._offset + len(self._raw["db"]) - TRACK_LOOKAHEAD
        return self._finalise(end)

    def _finalise(self, end: int) -> dict[str, np.ndarray]:
        start = self._next
        n = max(0, end - start)
        out = {name: np.zeros(n) for name in TRACK_FIELDS}
        if n == 0:
            return out
        p = self.p
        r = self._raw
        idx = np.arange(start, end) - self._offset
        for name in ("db", "f0", "centroid", "f1_frac", "f2_frac", "low_frac", "hiss_frac"):
            out[name] = r[name][idx]
        db_all = r["db"].tolist()
        # The level voice activity reads: a frame that is only the other voice's bleed is silence.
        bleed = _fill_holes(r["bleed"] > 0, TRACK_LOOKAHEAD)
        own_all = np.where(bleed, -120.0, r["db"]).tolist()
        bleed_all = bleed.tolist()
        periodic = (r["periodicity"] >= p.voicing).tolist()
        st_all = (12.0 * np.log2(np.maximum(r["f0"], 1.0) / 100.0)).tolist()
        f1, low = r["f1_frac"].tolist(), r["low_frac"].tolist()
        # Scalar work per frame: plain Python lists and floats here, numpy arrays at the end.
        o_vad, o_voiced, o_env, o_st, o_laugh = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
        o_sounding = [False] * n
        out["bleed"] = bleed[idx].astype(float)
        for j, i in enumerate(idx.tolist()):
            f = start + j
            db = db_all[i]
            # Noise floor: follows dips at once and creeps up 1.5 dB/s; it raises the thresholds in noise.
            self._floor = max(-80.0, min(db, self._floor + 0.05)) if self._floor is not None else max(-80.0, db)
            # Thresholds follow the speaker's level down for quiet voices and the floor up in noise.
            on_db = max(self._floor + 14.0, min(p.vad_on_db, self._level - 14.0))
            off_db = max(self._floor + 8.0, min(p.vad_off_db, self._level - 22.0))
            # Voice activity with hysteresis: on after two loud frames, off after a hangover.
            own = own_all[i]
            self._bleed_run = self._bleed_run + 1 if bleed_all[i] else 0
            if self._vad:
                self._below = self._below + 1 if own < off_db else 0
                # The hangover bridges pauses inside a turn; once the other voice has taken over
                # this microphone, the turn is over.
                if self._below > p.vad_hangover or self._bleed_run >= _BLEED_RELEASE:
                    self._vad = False
            elif own >= on_db and own_all[i + 1] >= off_db:
                self._vad = True
                self._below = 0
            o_vad[j] = self._vad
            o_sounding[j] = own >= off_db
            voiced = self._vad and periodic[i] and own > off_db
            o_voiced[j] = voiced
            # Loudness in [0, 1] relative to this voice's running level (automatic gain): the level
            # follows periodic frames well above the noise, so quiet voices are found too.
            if periodic[i] and own > self._floor + 14.0:
                self._level = max(-50.0, self._level + 0.01 * (db - self._level))
            top = self._level + 7.0
            bottom = max(self._floor + 4.0, top - 40.0)
            span = top - bottom
            e = min(1.0, max(0.0, (db - bottom) / span))
            e_prev = min(1.0, max(0.0, (db_all[max(i - 1, 0)] - bottom) / span))
            e_next = min(1.0, max(0.0, (db_all[i + 1] - bottom) / span))
            env = 0.25 * e_prev + 0.5 * e + 0.25 * e_next
            o_env[j] = env
            st = st_all[i]
            if voiced:
                self._baseline = st if math.isnan(self._baseline) else 0.97 * self._baseline + 0.03 * st
            rel = st - self._baseline if voiced and not math.isnan(self._baseline) else 0.0
            o_st[j] = rel
            self._since_accent += 1
            self._since_nucleus += 1
            w0, w1 = max(i - 2, 0), i + TRACK_LOOKAHEAD + 1
            # Pitch accent: a local F0 peak well above the speaker's running baseline, on a loud frame.
            if (
                voiced
                and rel > p.accent_st
                and env > 0.35
                and self._since_accent > 8
                and st >= max(st_all[k] if periodic[k] else -99.0 for k in range(w0, w1))
            ):
                out["accent"][j] = min(1.0, rel / 6.0)
                self._since_accent = 0
            # Syllable nucleus: a local loudness peak after a dip of at least 8 % of the range.
            dip = (db - min(db_all[max(i - 6, 0) : i + 1])) / span if self._vad and e > 0.3 else 0.0
            if dip > 0.08 and self._since_nucleus > 3 and db >= max(db_all[w0:w1]):
                strength = min(1.0, 0.4 + dip)
                out["nucleus"][j] = strength
                self._since_nucleus = 0
                self._nuclei.append((f, f1[i], low[i]))
                self._env_mean = 0.9 * self._env_mean + 0.1 * e
                accented = self._since_accent <= 3
                if accented or e > self._env_mean + 0.04:
                    out["stress"][j] = min(1.0, strength + (0.3 if accented else 0.0))
            rise = (db - db_all[max(i - 2, 0)]) / span
            if self._vad and rise > 0.25:
                out["onset"][j] = min(1.0, rise)
            o_laugh[j] = self._laughter()
        for name, values in (
            ("vad", o_vad),
            ("sounding", o_sounding),
            ("voiced", o_voiced),
            ("env", o_env),
            ("pitch_st", o_st),
            ("laugh", o_laugh),
        ):
            out[name] = np.array(values, float)
        self._next = end
        # Keep only the history later frames still look at.
        keep_from = max(0, end - self._offset - _HISTORY)
        if keep_from:
            for name in RAW_FIELDS:
                r[name] = r[name][keep_from:]
            self._offset += keep_from
        self._nuclei = [nu for nu in self._nuclei if nu[0] > end - 40]
        return out

    def _laughter(self) -> float:
        """Laughter-like burst: five evenly spaced nuclei at 3.5 to 7.5 per second on the same vowel.

        Speech at a similar syllable rate changes vowel from syllable to syllable (the F1 and low
        band fractions vary by 0.15 or more); "ha ha ha" keeps them within a few hundredths.
        """
        score = 0.0
        last = self._nuclei[-5:] if self._since_nucleus == 0 else ()
        if len(last) == 5 and last[-1][0] - last[0][0] <= 36:
            gaps = [b[0] - a[0] for a, b in zip(last, last[1:])]
            mean = sum(gaps) / 4.0
            same_vowel = _spread([n[1] for n in last]) + _spread([n[2] for n in last])
            if 4 <= mean <= 8.5 and _spread(gaps) <= 0.15 * mean and same_vowel < 0.08:
                score = 1.0
        self._laugh = max(score, self._laugh * 0.93)
        return self._laugh


def _spread(values: list[float]) -> float:
    """Population standard deviation of a few numbers (numpy's costs more than the arithmetic)."""
    mean = sum(values) / len(values)
    return math.sqrt(sum((v - mean) ** 2 for v in values) / len(values))
