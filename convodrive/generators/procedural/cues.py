"""Conversation cues that need a little of the future: the partner's pauses and self's turn starts.

A listener nods when the partner pauses, and a speaker breathes in and leans in before speaking.
Both are decided on features a few frames ahead of the frame being made, so frames are held back
``anticipation`` frames here (on top of the audio analysis' own look-ahead), and the generator
declares the sum as its look-ahead: frame f never reads audio past what that promises.

The cues depend on the features only (not on the take's seed), so one tracker serves every take.
Like the rest of the generator they are chunk-invariant: each frame's cues read a fixed window of
frames around it, however the frames arrived.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from convodrive.audio.analysis import FrameBatch

PAUSE_FRAMES = 5
"""Quiet frames (167 ms) that make a partner pause; fewer when the look-ahead cannot see them."""
PHRASE_FRAMES = 15
"""A pause follows a phrase: the partner sounded in at least a third of the 15 frames before it."""
TURN_QUIET_FRAMES = 15
"""Self starts a turn when speaking after at least 500 ms of silence."""
BREATH_FRAMES = 9
"""The in-breath before a turn starts up to 300 ms ahead of the voice, as the look-ahead allows."""
FALL_FRAMES = 12
"""Voiced frames before a pause whose pitch tells a falling (statement) end from a level or rise."""
_HISTORY = max(PHRASE_FRAMES, TURN_QUIET_FRAMES, FALL_FRAMES) + 1


@dataclasses.dataclass
class CueBatch:
    """A run of analysed frames with their conversation cues, each ``(n,)``:

    - ``pause``: 1 at the first frame of a partner pause after a phrase, else 0;
    - ``fall``: at those frames, how clearly the phrase ended on a pitch fall (0..1);
    - ``breath``: 1 on the frames before a turn of self's, where the in-breath and lean happen.
    """

    features: FrameBatch
    cues: dict[str, np.ndarray]

    @property
    def first(self) -> int:
        return self.features.first

    def __len__(self) -> int:
        return len(self.features)


class CueTracker:
    """Hold frames back ``anticipation`` frames and attach the cues that the future decides."""

    def __init__(self, anticipation: int) -> None:
        self.ahead = int(anticipation)
        self.pause_frames = min(PAUSE_FRAMES, self.ahead + 1)
        self.breath_frames = min(BREATH_FRAMES, self.ahead)
        self._buf: FrameBatch | None = None  # history + frames not yet emitted
        self._next = 0  # first frame not yet emitted

    def push(self, batch: FrameBatch | None, final: bool = False) -> CueBatch | None:
        """Add analysed frames; return the frames whose look-ahead is now complete (all, if ``final``)."""
        if batch is not None and len(batch):
            self._buf = batch if self._buf is None else FrameBatch.concat([self._buf, batch])
        if self._buf is None:
            return None
        buf = self._buf
        end = buf.first + len(buf)
        stop = end if final else end - self.ahead
        if stop <= self._next:
            return None
        lo, hi = self._next - buf.first, stop - buf.first
        out = CueBatch(_slice(buf, lo, hi), self._cues(buf, lo, hi))
        self._next = stop
        keep = max(0, hi - _HISTORY)
        self._buf = _slice(buf, keep, len(buf))
        return out

    def _cues(self, buf: FrameBatch, lo: int, hi: int) -> dict[str, np.ndarray]:
        """Cues of buffer rows ``lo .. hi-1``; rows before ``lo`` are history, rows past ``hi`` the
        look-ahead (past the buffer's end, which only the final push reads, the audio has ended:
        silence)."""
        n = hi - lo
        pad = self.pause_frames + self.breath_frames + 1
        tail = np.zeros(pad)

        def padded(voice: dict[str, np.ndarray], key: str) -> np.ndarray:
            # History before the buffer's start is unknown; the start of the audio is silence.
            head = np.zeros(_HISTORY) if buf.first == 0 else None
            x = voice[key].astype(float)
            parts = [x, tail] if head is None else [head, x, tail]
            return np.concatenate(parts)

        shift = _HISTORY if buf.first == 0 else 0
        sounding = padded(buf.other_voice, "sounding") > 0
        voiced = padded(buf.other_voice, "voiced") > 0
        pitch = padded(buf.other_voice, "pitch_st")
        self_vad = padded(buf.self_voice, "vad") > 0
        rows = np.arange(lo, hi) + shift
        pause = np.zeros(n)
        fall = np.zeros(n)
        for j, r in enumerate(rows.tolist()):
            if r < 1 or not sounding[r - 1] or sounding[r : r + self.pause_frames].any():
                continue
            if r - PHRASE_FRAMES < 0 or sounding[r - PHRASE_FRAMES : r].sum() * 3 < PHRASE_FRAMES:
                continue
            pause[j] = 1.0
            fall[j] = _pitch_fall(pitch[max(0, r - FALL_FRAMES) : r], voiced[max(0, r - FALL_FRAMES) : r])
        breath = np.zeros(n)
        if self.breath_frames:
            # Turn starts: self's voice begins after TURN_QUIET_FRAMES of silence.
            starts = [
                g
                for g in range(max(TURN_QUIET_FRAMES, rows[0] + 1), rows[-1] + self.breath_frames + 1)
                if self_vad[g] and not self_vad[g - TURN_QUIET_FRAMES : g].any()
            ]
            for g in starts:
                a, b = max(g - self.breath_frames, rows[0]), min(g, rows[-1] + 1)
                breath[a - rows[0] : b - rows[0]] = 1.0
        return {"pause": pause, "fall": fall, "breath": breath}


def _pitch_fall(pitch: np.ndarray, voiced: np.ndarray) -> float:
    """0..1: how far the last voiced frame lies below the phrase's recent peak (4 semitones = 1)."""
    st = pitch[voiced]
    if len(st) < 3:
        return 0.0
    return float(np.clip((st.max() - st[-1]) / 4.0, 0.0, 1.0))


def _slice(batch: FrameBatch, lo: int, hi: int) -> FrameBatch:
    return FrameBatch(
        batch.first + lo,
        {k: v[lo:hi] for k, v in batch.self_voice.items()},
        {k: v[lo:hi] for k, v in batch.other_voice.items()},
        batch.visemes[lo:hi],
        batch.from_phones[lo:hi],
    )
