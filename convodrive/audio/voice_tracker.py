"""The tracked stage of the speech features of one voice (``features`` has the raw stage): voice
activity with hysteresis, whether a frame sounds, the smoothed envelope, pitch accents, syllable
nuclei and onsets, laughter-like bursts, each decided with ``TRACK_LOOKAHEAD`` raw frames of look-ahead."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from convodrive.audio.features import RAW_FIELDS, TRACK_LOOKAHEAD

_HISTORY = 48
"""Raw frames of history the tracker keeps (laughter looks back 1 s)."""
_BLEED_RELEASE = 3
"""Consecutive bleed frames (the other voice alone in this microphone) that end this voice's turn."""


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


@dataclasses.dataclass(frozen=True)
class _Window:
    """The raw frames a ``_finalise`` call reads, as Python lists (scalar work per frame)."""

    db: list[float]
    own: list[float]
    """``db`` with frames that only carry the other voice's bleed at -120 dBFS."""
    bleed: list[bool]
    periodic: list[bool]
    st: list[float]
    """F0 in semitones above 100 Hz."""
    f1: list[float]
    low: list[float]


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
        r = self._raw
        idx = np.arange(start, end) - self._offset
        for name in ("db", "f0", "centroid", "f1_frac", "f2_frac", "low_frac", "hiss_frac"):
            out[name] = r[name][idx]
        # The level voice activity reads: a frame that is only the other voice's bleed is silence.
        bleed = _fill_holes(r["bleed"] > 0, TRACK_LOOKAHEAD)
        w = _Window(
            db=r["db"].tolist(),
            own=np.where(bleed, -120.0, r["db"]).tolist(),
            bleed=bleed.tolist(),
            periodic=(r["periodicity"] >= self.p.voicing).tolist(),
            st=(12.0 * np.log2(np.maximum(r["f0"], 1.0) / 100.0)).tolist(),
            f1=r["f1_frac"].tolist(),
            low=r["low_frac"].tolist(),
        )
        # Scalar work per frame: plain Python lists and floats here, numpy arrays at the end.
        cols: dict[str, list[Any]] = {
            name: [0.0] * n for name in ("vad", "sounding", "voiced", "env", "pitch_st", "laugh")
        }
        out["bleed"] = bleed[idx].astype(float)
        for j, i in enumerate(idx.tolist()):
            self._track_frame(w, i, j, start + j, out, cols)
        for name, values in cols.items():
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

    def _track_frame(
        self, w: _Window, i: int, j: int, f: int, out: dict[str, np.ndarray], cols: dict[str, list[Any]]
    ) -> None:
        """Frame ``f`` (raw index ``i``, output row ``j``): activity, envelope, pitch, peaks, laughter."""
        own, off_db = self._activity(w, i)
        cols["vad"][j] = self._vad
        cols["sounding"][j] = own >= off_db
        voiced = self._vad and w.periodic[i] and own > off_db
        cols["voiced"][j] = voiced
        env, e, span = self._envelope(w, i, own)
        cols["env"][j] = env
        st = w.st[i]
        if voiced:
            self._baseline = st if math.isnan(self._baseline) else 0.97 * self._baseline + 0.03 * st
        rel = st - self._baseline if voiced and not math.isnan(self._baseline) else 0.0
        cols["pitch_st"][j] = rel
        self._since_accent += 1
        self._since_nucleus += 1
        self._peaks(w, i, j, f, out, voiced, rel, env, e, span)
        cols["laugh"][j] = self._laughter()

    def _activity(self, w: _Window, i: int) -> tuple[float, float]:
        """Update the noise floor and voice activity at raw frame ``i``; (own level, off threshold)."""
        p = self.p
        db = w.db[i]
        # Noise floor: follows dips at once and creeps up 1.5 dB/s; it raises the thresholds in noise.
        self._floor = max(-80.0, min(db, self._floor + 0.05)) if self._floor is not None else max(-80.0, db)
        # Thresholds follow the speaker's level down for quiet voices and the floor up in noise.
        on_db = max(self._floor + 14.0, min(p.vad_on_db, self._level - 14.0))
        off_db = max(self._floor + 8.0, min(p.vad_off_db, self._level - 22.0))
        # Voice activity with hysteresis: on after two loud frames, off after a hangover.
        own = w.own[i]
        self._bleed_run = self._bleed_run + 1 if w.bleed[i] else 0
        if self._vad:
            self._below = self._below + 1 if own < off_db else 0
            # The hangover bridges pauses inside a turn; once the other voice has taken over
            # this microphone, the turn is over.
            if self._below > p.vad_hangover or self._bleed_run >= _BLEED_RELEASE:
                self._vad = False
        elif own >= on_db and w.own[i + 1] >= off_db:
            self._vad = True
            self._below = 0
        return own, off_db

    def _envelope(self, w: _Window, i: int, own: float) -> tuple[float, float, float]:
        """Loudness in [0, 1] relative to this voice's running level (automatic gain): the level
        follows periodic frames well above the noise, so quiet voices are found too. Returns the
        smoothed envelope, this frame's loudness and the span of the range."""
        db, floor = w.db[i], self._floor
        assert floor is not None
        if w.periodic[i] and own > floor + 14.0:
            self._level = max(-50.0, self._level + 0.01 * (db - self._level))
        top = self._level + 7.0
        bottom = max(floor + 4.0, top - 40.0)
        span = top - bottom
        e = min(1.0, max(0.0, (db - bottom) / span))
        e_prev = min(1.0, max(0.0, (w.db[max(i - 1, 0)] - bottom) / span))
        e_next = min(1.0, max(0.0, (w.db[i + 1] - bottom) / span))
        return 0.25 * e_prev + 0.5 * e + 0.25 * e_next, e, span

    def _peaks(
        self,
        w: _Window,
        i: int,
        j: int,
        f: int,
        out: dict[str, np.ndarray],
        voiced: bool,
        rel: float,
        env: float,
        e: float,
        span: float,
    ) -> None:
        """Pitch accents, syllable nuclei (with stress) and onsets, decided with the look-ahead."""
        db, db_all, st_all, periodic = w.db[i], w.db, w.st, w.periodic
        w0, w1 = max(i - 2, 0), i + TRACK_LOOKAHEAD + 1
        # Pitch accent: a local F0 peak well above the speaker's running baseline, on a loud frame.
        if (
            voiced
            and rel > self.p.accent_st
            and env > 0.35
            and self._since_accent > 8
            and st_all[i] >= max(st_all[k] if periodic[k] else -99.0 for k in range(w0, w1))
        ):
            out["accent"][j] = min(1.0, rel / 6.0)
            self._since_accent = 0
        # Syllable nucleus: a local loudness peak after a dip of at least 8 % of the range.
        dip = (db - min(db_all[max(i - 6, 0) : i + 1])) / span if self._vad and e > 0.3 else 0.0
        if dip > 0.08 and self._since_nucleus > 3 and db >= max(db_all[w0:w1]):
            strength = min(1.0, 0.4 + dip)
            out["nucleus"][j] = strength
            self._since_nucleus = 0
            self._nuclei.append((f, w.f1[i], w.low[i]))
            self._env_mean = 0.9 * self._env_mean + 0.1 * e
            accented = self._since_accent <= 3
            if accented or e > self._env_mean + 0.04:
                out["stress"][j] = min(1.0, strength + (0.3 if accented else 0.0))
        rise = (db - db_all[max(i - 2, 0)]) / span
        if self._vad and rise > 0.25:
            out["onset"][j] = min(1.0, rise)

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
