"""Streaming dyadic analysis: both voices' per-frame features and self's visemes, chunk by chunk.

Each voice's activity is decided with the other channel in view: frames where a channel only
carries the other person's voice through its microphone (bleed, ``audio.bleed``) do not count as
that voice speaking.

``DyadicAnalyzer.push`` takes audio as it arrives, in chunks of any size, and returns the frames
whose features became final; ``finish`` pads the end with silence and returns the rest. Frame f is
final once ``LOOKAHEAD_SAMPLES`` (115 ms) past its start have arrived: that is what its voice
features need (see ``features``), and its phone is read from the decoder after the last 50 ms block
that ends within them, so self's phones cost no latency beyond the features' (and never less than
50 ms of decoded audio after the frame). The partner's latency in a live run is this look-ahead.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from convodrive.audio.bleed import bleed_frames
from convodrive.audio.features import TRACK_LOOKAHEAD, WINDOW, frame_centre, frame_edge, raw_frames, samples_needed
from convodrive.audio.phones import BLOCK, PhoneTracker
from convodrive.audio.source import ANALYSIS_RATE, DyadicAudio
from convodrive.audio.visemes import NUM_VISEMES, spectral_visemes
from convodrive.audio.voice_tracker import VoiceParams, VoiceTracker


def _features_due(f: int) -> int:
    """Samples that must have arrived before frame ``f``'s features (and so its phone) are final."""
    return samples_needed(f + TRACK_LOOKAHEAD + 1)


LOOKAHEAD_SAMPLES = max(_features_due(f) - int(frame_edge(f)) for f in range(3))
"""Audio past a frame's start that the analysis needs before the frame is final (1846: 115 ms);
the same for every frame, up to the frame grid's rounding, which repeats every 3 frames."""
LOOKAHEAD_FRAMES = -(-LOOKAHEAD_SAMPLES * 30 // ANALYSIS_RATE) - 1
"""The same in whole frames, as the generator contract declares it: frame f may depend on audio up to
``(f + LOOKAHEAD_FRAMES + 1) / 30`` s (3: 100 ms)."""


@dataclasses.dataclass
class FrameBatch:
    """Features of frames ``first .. first + len - 1`` for self and the partner."""

    first: int
    self_voice: dict[str, np.ndarray]
    other_voice: dict[str, np.ndarray]
    visemes: np.ndarray
    """(n, 15) viseme weights of self's mouth."""
    from_phones: np.ndarray
    """(n,) True where the viseme came from recognised phones, False where from the spectrum."""

    def __len__(self) -> int:
        return len(self.visemes)

    @classmethod
    def concat(cls, batches: list[FrameBatch]) -> FrameBatch:
        def cat(dicts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
            return {k: np.concatenate([d[k] for d in dicts]) for k in dicts[0]}

        return cls(
            batches[0].first,
            cat([b.self_voice for b in batches]),
            cat([b.other_voice for b in batches]),
            np.concatenate([b.visemes for b in batches]),
            np.concatenate([b.from_phones for b in batches]),
        )


class DyadicAnalyzer:
    def __init__(self, params: VoiceParams | None = None, phones: bool = True) -> None:
        self.params = params or VoiceParams()
        self._self = VoiceTracker(self.params)
        self._other = VoiceTracker(self.params)
        self._phones = PhoneTracker(self.params.vad_off_db) if phones else None
        self._buf_start = -(WINDOW // 2)  # absolute index of the buffers' first sample
        self._buf_self = np.zeros(WINDOW // 2, np.float32)
        self._buf_other = np.zeros(WINDOW // 2, np.float32)
        self._received = 0
        self._raw_done = 0
        self._pending: list[tuple[dict[str, np.ndarray], dict[str, np.ndarray]]] = []
        self._pending_first = 0
        self._next_block = 0
        self._next_phone_frame = 0
        self._vis_decided: list[np.ndarray] = []  # phone viseme per frame, from _vis_first on
        self._vis_first = 0
        self._emitted = 0

    # -- input ---------------------------------------------------------------------------------
    def push(self, self_voice: np.ndarray, other_voice: np.ndarray) -> FrameBatch | None:
        self._append(self_voice, other_voice)
        return self._advance()

    def finish(self, num_frames: int) -> FrameBatch | None:
        """Pad with silence, finalise every frame up to ``num_frames`` and release the decoder."""
        need = _features_due(num_frames - 1)
        if need > self._received:
            pad = np.zeros(need - self._received, np.float32)
            self._append(pad, pad)
        batch = self._advance(limit=num_frames)
        if self._phones is not None:
            self._phones.close()
        return batch

    def close(self) -> None:
        if self._phones is not None:
            self._phones.close()

    def _append(self, a: np.ndarray, b: np.ndarray) -> None:
        self._buf_self = np.concatenate([self._buf_self, np.asarray(a, np.float32)])
        self._buf_other = np.concatenate([self._buf_other, np.asarray(b, np.float32)])
        self._received += len(a)

    # -- processing ----------------------------------------------------------------------------
    def _advance(self, limit: int | None = None) -> FrameBatch | None:
        # Raw features of every frame whose window has arrived.
        n = max(self._raw_done, int(((self._received - WINDOW // 2) * 3 / 800 + 1) // 2) + 1)
        while n > self._raw_done and samples_needed(n) > self._received:
            n -= 1
        while samples_needed(n + 1) <= self._received:
            n += 1
        if n > self._raw_done:
            count = n - self._raw_done
            raw_s = raw_frames(self._buf_self, self._buf_start, self._raw_done, count)
            raw_o = raw_frames(self._buf_other, self._buf_start, self._raw_done, count)
            raw_s["bleed"], raw_o["bleed"] = bleed_frames(
                self._buf_self,
                self._buf_other,
                self._buf_start,
                self._raw_done,
                count,
                np.stack([raw_s["db"], raw_o["db"]]),
            )
            s = self._self.push(raw_s)
            o = self._other.push(raw_o)
            self._raw_done = n
            if len(s["db"]):
                self._pending.append((s, o))
        # Phone decisions: after block b, every frame whose features are due before block b+1 ends.
        if self._phones is not None:
            while (self._next_block + 1) * BLOCK <= self._received:
                b = self._next_block
                lo = (b * BLOCK) - self._buf_start
                self._phones.feed_block(b, self._buf_self[lo : lo + BLOCK])
                first = last = self._next_phone_frame
                while _features_due(last) < (b + 2) * BLOCK:
                    last += 1
                frames = np.arange(first, last)
                self._vis_decided.append(self._phones.viseme_at(frame_centre(frames) // 160))
                self._next_phone_frame = last
                self._next_block += 1
        self._trim()
        return self._emit(limit)

    def _trim(self) -> None:
        keep = samples_needed(self._raw_done + 1) - WINDOW - 1600
        if self._phones is not None:
            keep = min(keep, self._next_block * BLOCK)
        drop = keep - self._buf_start
        if drop > 16_000:
            self._buf_self = self._buf_self[drop:]
            self._buf_other = self._buf_other[drop:]
            self._buf_start += drop

    def _emit(self, limit: int | None) -> FrameBatch | None:
        if not self._pending:
            return None
        s = {k: np.concatenate([p[0][k] for p in self._pending]) for k in self._pending[0][0]}
        o = {k: np.concatenate([p[1][k] for p in self._pending]) for k in self._pending[0][1]}
        ready = len(s["db"])
        if self._phones is not None:
            decided = np.concatenate(self._vis_decided) if self._vis_decided else np.zeros(0, np.int64)
            ready = min(ready, self._vis_first + len(decided) - self._pending_first)
        if limit is not None:
            ready = min(ready, limit - self._pending_first)
        if ready <= 0:
            self._pending = [(s, o)]
            return None
        first = self._pending_first
        take_s = {k: v[:ready] for k, v in s.items()}
        take_o = {k: v[:ready] for k, v in o.items()}
        visemes = spectral_visemes(
            take_s["f1_frac"],
            take_s["f2_frac"],
            take_s["low_frac"],
            take_s["hiss_frac"],
            take_s["voiced"],
            take_s["vad"],
        )
        from_phones = np.zeros(ready, bool)
        if self._phones is not None:
            phone = decided[first - self._vis_first : first - self._vis_first + ready]
            ok = (phone >= 0) & (take_s["vad"] > 0)
            onehot = np.zeros((ready, NUM_VISEMES))
            onehot[np.arange(ready), np.maximum(phone, 0)] = 1.0
            visemes = np.where(ok[:, None], onehot, visemes)
            from_phones = ok
            consumed = first + ready
            self._vis_decided = [decided[consumed - self._vis_first :]]
            self._vis_first = consumed
        self._pending = [({k: v[ready:] for k, v in s.items()}, {k: v[ready:] for k, v in o.items()})]
        self._pending_first = first + ready
        self._emitted = first + ready
        return FrameBatch(first, take_s, take_o, visemes, from_phones)


def analyse(audio: DyadicAudio, params: VoiceParams | None = None, phones: bool = False) -> FrameBatch:
    """Offline: the features of every frame of ``audio`` (equal to streaming it, chunk by chunk)."""
    analyzer = DyadicAnalyzer(params, phones=phones)
    try:
        parts = [analyzer.push(audio.self_voice, audio.other_voice), analyzer.finish(audio.num_frames)]
    finally:
        analyzer.close()
    return FrameBatch.concat([p for p in parts if p is not None])


def voice_activity(audio: DyadicAudio, params: VoiceParams | None = None) -> np.ndarray:
    """(T, 2) voice activity of self and the partner per motion frame, as generators see it."""
    batch = analyse(audio, params)
    return np.stack([batch.self_voice["vad"], batch.other_voice["vad"]], axis=1).astype(np.float32)
