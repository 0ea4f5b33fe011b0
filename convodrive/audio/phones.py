"""Streaming phone recognition with pocketsphinx's bundled English model, decoded as a phone loop.

Audio is fed in fixed 100 ms blocks aligned to the stream's start, so the partial hypotheses (and
everything derived from them) are the same however the caller chunks the audio. Quiet blocks end
the utterance and are skipped: the decoder only hears speech, which keeps it fast and bounds the
cost of reading back each partial segmentation.

``viseme_at`` answers, after block b has been decoded, which viseme covers a motion frame, or
``-1`` where the decoder has nothing for that time (not decoded yet, or a skipped quiet block):
the caller falls back to the spectral visemes there.
"""

from __future__ import annotations

import bisect

import numpy as np

from convodrive.audio.source import CHUNK_SAMPLES
from convodrive.audio.visemes import phone_viseme

BLOCK = CHUNK_SAMPLES
_MAX_UTTERANCE_BLOCKS = 150  # 15 s; longer speech is decoded in pieces


def pocketsphinx_available() -> bool:
    try:
        import pocketsphinx  # noqa: F401
    except ImportError:
        return False
    return True


class PhoneTracker:
    """Phone-loop decoding of one voice, block by block; results as a 10 ms viseme timeline."""

    def __init__(self, silence_db: float = -48.0) -> None:
        self.silence_db = silence_db
        self._decoder = _acquire_decoder()  # every stream starts from the same normalisation
        self._in_utt = False
        self._utt_start = 0  # in 10 ms frames
        self._utt_blocks = 0
        # Committed timeline (finished utterances): parallel lists of start, end (10 ms frames), viseme.
        self._starts: list[int] = []
        self._ends: list[int] = []
        self._vis: list[int] = []
        self._partial: list[tuple[int, int, int]] = []

    def feed_block(self, index: int, block: np.ndarray) -> None:
        """Decode block ``index`` (``BLOCK`` samples at 16 kHz, float; shorter only at the end)."""
        d = self._decoder
        sub = block[: len(block) // 160 * 160].reshape(-1, 160) if len(block) >= 160 else block.reshape(1, -1)
        loudest = 10 * np.log10(np.max(np.mean(np.square(sub, dtype=np.float64), axis=1)) + 1e-10) if len(block) else -100.0
        silent = loudest < self.silence_db
        if silent:
            if self._in_utt:
                self._end_utterance()
            return
        if not self._in_utt:
            d.start_utt()
            self._in_utt = True
            self._utt_start = index * BLOCK // 160
            self._utt_blocks = 0
        pcm = (np.clip(block, -1.0, 1.0) * 32767.0).astype(np.int16)
        d.process_raw(pcm.tobytes(), False, False)
        self._utt_blocks += 1
        if self._utt_blocks >= _MAX_UTTERANCE_BLOCKS:
            self._end_utterance()
        else:
            self._partial = self._segments()

    def finish(self) -> None:
        if self._in_utt:
            self._end_utterance()

    def _segments(self) -> list[tuple[int, int, int]]:
        base = self._utt_start
        return [(base + s.start_frame, base + s.end_frame + 1, phone_viseme(s.word)) for s in self._decoder.seg()]

    def _end_utterance(self) -> None:
        self._decoder.end_utt()
        for s, e, v in self._segments():
            self._starts.append(s)
            self._ends.append(e)
            self._vis.append(v)
        self._partial = []
        self._in_utt = False
        # Older segments are never asked for again once a later utterance ended; keep the list short.
        if len(self._starts) > 400:
            del self._starts[:200], self._ends[:200], self._vis[:200]

    def viseme_at(self, frames_10ms: np.ndarray) -> np.ndarray:
        """Viseme covering each 10 ms frame, or -1 where nothing was decoded (yet): not reached by
        the decoder, or a block skipped as quiet (where the voice tracker may still hear speech)."""
        out = np.full(len(frames_10ms), -1, np.int64)
        for j, t in enumerate(frames_10ms.tolist()):
            if self._in_utt and t >= self._utt_start:
                out[j] = _lookup(self._partial, t)
                continue
            i = bisect.bisect_right(self._starts, t) - 1
            if i >= 0 and t < self._ends[i]:
                out[j] = self._vis[i]
        return out

    def close(self) -> None:
        """Give the decoder back to the pool; the tracker is unusable afterwards."""
        if self._decoder is not None:
            if self._in_utt:
                self._decoder.end_utt()
            _POOL.append(self._decoder)
            self._decoder = None


def _lookup(segments: list[tuple[int, int, int]], t: int) -> int:
    for s, e, v in reversed(segments):
        if s <= t < e:
            return v
    return -1


_POOL: list = []


def _acquire_decoder():
    """A decoder from the pool, reset to the initial normalisation; loading one takes 0.25 s."""
    try:
        decoder = _POOL.pop()
    except IndexError:
        decoder = None
    if decoder is not None:
        decoder.reinit_feat()  # forget the normalisation the last stream adapted
    else:
        from pocketsphinx import Decoder, get_model_path

        decoder = Decoder(
            hmm=get_model_path("en-us/en-us"), allphone=get_model_path("en-us/en-us-phone.lm.bin"),
            loglevel="FATAL", lw=2.0, pip=0.3, beam=1e-10, pbeam=1e-10, ds=2, topn=2,
        )
    return decoder
