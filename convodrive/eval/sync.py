"""Audio–motion sync: when speech starts in a recording versus when the mouth starts to open.

A live run records what the speaker actually played (``--monitor``) and knows when each motion
frame went out; both on ``time.monotonic``. Pairing each speech onset with the nearest mouth
opening gives the audio–motion offset a viewer sees (positive: the mouth opens after the sound
starts). The same pairing on the audio the generator was given, against frame times k/30, gives
the generator's own offset (what it does on purpose, e.g. opening the mouth a frame early); their
difference is the error of the playback clock alone. ITU-R BT.1359 puts the limits of detection
at 45 ms of audio ahead and 125 ms behind.
"""

from __future__ import annotations

import dataclasses

import numpy as np

HOP_SECONDS = 0.005
MIN_SILENCE_SECONDS = 0.15
"""A speech onset follows at least this much silence (so syllables are not onsets)."""
MOUTH_OPEN = 0.1
"""``jawOpen`` above this is an open mouth."""
MIN_CLOSED_FRAMES = 5
PAIR_WINDOW_SECONDS = 0.2
"""Onsets further apart than this are not the same event."""


def level_db(samples: np.ndarray, rate: int, hop_seconds: float = HOP_SECONDS) -> np.ndarray:
    """RMS level in dBFS of consecutive hops."""
    hop = max(1, int(round(hop_seconds * rate)))
    n = len(samples) // hop
    frames = np.asarray(samples[: n * hop], np.float64).reshape(n, hop)
    return 10.0 * np.log10(np.mean(frames**2, axis=1) + 1e-12)


def speech_onsets(db: np.ndarray, hop_seconds: float = HOP_SECONDS) -> np.ndarray:
    """Start times (s) of speech after silence, from hop levels: active above a threshold set
    between the level of the loud and the quiet hops."""
    if not len(db):
        return np.zeros(0)
    loud, quiet = np.percentile(db, 97), np.percentile(db, 10)
    if loud - quiet < 20.0:  # no speech to speak of
        return np.zeros(0)
    active = db > max(loud - 30.0, quiet + 15.0)
    return _onsets(active, int(round(MIN_SILENCE_SECONDS / hop_seconds))) * hop_seconds


def mouth_onsets(jaw_open: np.ndarray) -> np.ndarray:
    """Frame indices where the mouth opens after being closed for ``MIN_CLOSED_FRAMES``."""
    return _onsets(np.asarray(jaw_open) > MOUTH_OPEN, MIN_CLOSED_FRAMES)


def _onsets(active: np.ndarray, quiet_before: int) -> np.ndarray:
    idx = np.flatnonzero(active)
    if not len(idx):
        return np.zeros(0, np.int64)
    gaps = np.diff(np.concatenate([[-(quiet_before + 1)], idx]))
    return idx[gaps > quiet_before]


@dataclasses.dataclass(frozen=True)
class SyncFigure:
    """Offsets (ms, motion minus audio) of paired onsets, and when each audio onset was."""

    offsets_ms: np.ndarray
    times: np.ndarray
    audio_onsets: int
    motion_onsets: int

    def summary(self) -> dict[str, float | int | None]:
        n = len(self.offsets_ms)
        out: dict[str, float | int | None] = {
            "pairs": n,
            "speech_onsets": self.audio_onsets,
            "mouth_onsets": self.motion_onsets,
            "median_ms": None,
            "mean_ms": None,
            "min_ms": None,
            "max_ms": None,
            "drift_ms_per_10min": None,
        }
        if n:
            out.update(
                median_ms=round(float(np.median(self.offsets_ms)), 1),
                mean_ms=round(float(np.mean(self.offsets_ms)), 1),
                min_ms=round(float(self.offsets_ms.min()), 1),
                max_ms=round(float(self.offsets_ms.max()), 1),
            )
        if n >= 3 and np.ptp(self.times) >= 30.0:
            slope = np.polyfit(self.times, self.offsets_ms, 1)[0]
            out["drift_ms_per_10min"] = round(float(slope * 600.0), 1)
        return out


def pair_onsets(audio: np.ndarray, motion: np.ndarray, window: float = PAIR_WINDOW_SECONDS) -> SyncFigure:
    """Pair each audio onset (s) with the nearest motion onset (s) within ``window``."""
    audio, motion = np.sort(np.asarray(audio, float)), np.sort(np.asarray(motion, float))
    offsets, times = [], []
    for t in audio:
        if not len(motion):
            break
        j = int(np.argmin(np.abs(motion - t)))
        if abs(motion[j] - t) <= window:
            offsets.append(1000.0 * (motion[j] - t))
            times.append(t)
    return SyncFigure(np.asarray(offsets), np.asarray(times), len(audio), len(motion))


class LevelMeter:
    """``level_db`` of a stream fed in pieces of any size (the voice the generator heard)."""

    def __init__(self, rate: int, hop_seconds: float = HOP_SECONDS) -> None:
        self.rate = rate
        self.hop = max(1, int(round(hop_seconds * rate)))
        self._rest = np.zeros(0, np.float32)
        self._levels: list[np.ndarray] = []

    def push(self, samples: np.ndarray) -> None:
        data = np.concatenate([self._rest, np.asarray(samples, np.float32)])
        n = len(data) // self.hop * self.hop
        if n:
            self._levels.append(level_db(data[:n], self.rate, self.hop / self.rate))
        self._rest = data[n:]

    @property
    def db(self) -> np.ndarray:
        return np.concatenate(self._levels) if self._levels else np.zeros(0)
