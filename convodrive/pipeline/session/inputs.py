"""Audio a voice agent pushes into a live session: the partner's, and the agent's own by segment.

The framework's threads only copy and enqueue (``push``, ``feed``); resampling happens on the
session's side (the producer pulls the partner, the self-voice feeder reads the voice), so no
call a framework makes waits on convodrive.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from convodrive.audio.live.capture import Captured, PartnerInput
from convodrive.audio.live.ring import SampleRing
from convodrive.audio.live.self_voice import VoiceSource
from convodrive.audio.resample import StreamResampler
from convodrive.audio.source import ANALYSIS_RATE

Segment = Hashable
"""Names one stretch of the agent's speech (a TTS context, a reply): ended, cleared as a whole."""


def as_mono(pcm: Any, channels: int = 1) -> np.ndarray:
    """s16le bytes, or an int16 or float array, interleaved over ``channels``, as float32 mono."""
    if isinstance(pcm, bytes | bytearray | memoryview):
        data = np.frombuffer(bytes(pcm), dtype="<i2").astype(np.float32) / 32768.0
    else:
        arr = np.asarray(pcm)
        data = arr.astype(np.float32) / 32768.0 if arr.dtype == np.int16 else arr.astype(np.float32, copy=True)
    if channels > 1:
        data = data.reshape(-1, channels).mean(axis=1)
    return data.reshape(-1)


class _Resamplers:
    """One streaming resampler per input rate, to ``rate``."""

    def __init__(self, rate: int) -> None:
        self.rate = rate
        self._by_rate: dict[int, StreamResampler] = {}

    def push(self, data: np.ndarray, rate: int) -> tuple[np.ndarray, float]:
        """Resampled samples, and how many seconds older their first sample is than the input's."""
        if rate == self.rate:
            return data, 0.0
        r = self._by_rate.get(rate)
        if r is None:
            r = self._by_rate[rate] = StreamResampler(rate, self.rate)
        return r.push(data), r.latency_samples / self.rate

    def finish(self) -> np.ndarray:
        tails = [r.finish() for r in self._by_rate.values()]
        self._by_rate.clear()
        return np.concatenate(tails) if tails else np.zeros(0, np.float32)


class PushedPartner(PartnerInput):
    """The partner's audio as the framework hands it over, with capture times (monotonic)."""

    describe = "pushed by the voice agent"

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._blocks: collections.deque[tuple[np.ndarray, int, float]] = collections.deque()
        self._to_analysis = _Resamplers(ANALYSIS_RATE)
        self._closed = False
        self.pushed = 0.0

    def start(self) -> None:
        pass

    def push(self, data: np.ndarray, rate: int, captured: float) -> None:
        with self._lock:
            self._blocks.append((data, rate, captured))
            self.pushed += len(data) / rate

    def pull(self) -> list[Captured]:
        with self._lock:
            blocks = list(self._blocks)
            self._blocks.clear()
        out = []
        for data, rate, captured in blocks:
            resampled, older = self._to_analysis.push(data, rate)
            if len(resampled):
                out.append((resampled, captured - older))
        return out

    def ended(self) -> bool:
        return self._closed

    def close(self) -> None:
        self._closed = True

    def report(self) -> dict[str, Any]:
        return {"source": self.describe, "pushed_seconds": round(self.pushed, 3)}


class QueuedVoice(VoiceSource):
    """The agent's voice fed by segment, read by ``SelfVoiceFeeder`` into the playback ring.

    It keeps at most ``ahead`` seconds queued in the ring (the rest waits here, where a clear
    drops it for free), and notes where in the ring each segment's samples went (``marks``), so
    the session knows when each is played and can take back what a pause must not lose.
    ``on_start(segment, ring_position)`` is called when a segment's first sample is queued."""

    finite = False
    describe = "pushed by the voice agent"

    def __init__(
        self,
        rate: int,
        ring: SampleRing,
        ahead: float,
        on_start: Callable[[Segment, int], None],
        on_queued: Callable[[int, float], None] | None = None,
    ) -> None:
        self.rate = rate
        self.on_queued = on_queued
        """Called with each queued stretch's ring position and the time it was fed."""
        self.ring = ring
        self.ahead = int(round(ahead * rate))
        self.on_start = on_start
        self._lock = threading.Lock()
        self._queue: collections.deque[tuple[Segment, np.ndarray, int, float]] = collections.deque()
        """(segment, samples, their rate, monotonic time fed); empty samples end the segment."""
        self._resample = _Resamplers(rate)
        self.dead: set[Segment] = set()
        self.ended: set[Segment] = set()
        self.marks: collections.deque[tuple[Segment, int, int, np.ndarray, float]] = collections.deque(maxlen=4096)
        """(segment, ring position, offset into the segment, samples, time fed) of what was queued."""
        self._offset: dict[Segment, int] = {}
        self._current: Segment | None = None
        self._held = False
        self.dropped = 0.0

    # -- the framework's side (any thread) ---------------------------------------------------------
    def feed(self, segment: Segment, data: np.ndarray, rate: int) -> bool:
        with self._lock:
            if segment in self.dead:
                self.dropped += len(data) / rate
                return False
            self._queue.append((segment, data, rate, time.monotonic()))
            return True

    def end(self, segment: Segment) -> None:
        with self._lock:
            if segment not in self.dead:
                self._queue.append((segment, np.zeros(0, np.float32), self.rate, time.monotonic()))

    def queued_seconds(self) -> float:
        with self._lock:
            return sum(len(item[1]) / item[2] for item in self._queue)

    def clear(self) -> set[Segment]:
        """Drop everything not yet in the ring; the segments known so far are dead."""
        with self._lock:
            known = {item[0] for item in self._queue} | {m[0] for m in self.marks} | set(self._offset)
            self.dropped += sum(len(item[1]) / item[2] for item in self._queue)
            self._queue.clear()
            self.dead |= known
            self._current = None
            return known

    def hold(self, cut: int) -> None:
        """Pause: stop queueing, and take back what the ring holds from position ``cut`` on."""
        with self._lock:
            self._held = True
            back = []
            for segment, pos, offset, data, fed in self.marks:
                if pos + len(data) > cut and segment not in self.dead:
                    skip = max(cut - pos, 0)
                    back.append((segment, data[skip:], self.rate, fed))
                    self._offset[segment] = min(self._offset.get(segment, offset), offset + skip)
            while self.marks and self.marks[-1][1] + len(self.marks[-1][3]) > cut:
                self.marks.pop()
            self._queue.extendleft(reversed(back))
            self._current = None

    def release(self) -> None:
        with self._lock:
            self._held = False

    # -- the feeder's side -------------------------------------------------------------------------
    def read(self, max_samples: int, timeout: float) -> np.ndarray | None:
        room = min(int(max_samples), self.ahead - self.ring.available())
        out: list[np.ndarray] = []
        got = 0
        with self._lock:
            while room - got > 0 and self._queue and not self._held:
                segment, data, rate, fed = self._queue[0]
                if not len(data):  # the segment's end: flush its resampler's tail
                    self._queue.popleft()
                    self.ended.add(segment)
                    tail = self._resample.finish()
                    data, rate = tail, self.rate
                    if not len(tail):
                        continue
                    self._queue.appendleft((segment, data, rate, fed))
                    continue
                if rate != self.rate:
                    data, _ = self._resample.push(data, rate)
                    self._queue[0] = (segment, data, self.rate, fed)
                    if not len(data):
                        self._queue.popleft()
                        continue
                take = data[: room - got]
                if len(take) == len(data):
                    self._queue.popleft()
                else:
                    self._queue[0] = (segment, data[len(take) :], rate, fed)
                position = self.ring.write_pos + got
                if segment != self._current:  # it starts where it is heard: the ring skips what the
                    self._current = segment  # speaker passed before it came (an underrun)
                    self.on_start(segment, max(position, self.ring.read_pos))
                offset = self._offset.get(segment, 0)
                self.marks.append((segment, position, offset, take, fed))
                if self.on_queued is not None:
                    self.on_queued(position, fed)
                self._offset[segment] = offset + len(take)
                out.append(take)
                got += len(take)
        if not out:
            time.sleep(min(timeout, 0.002))
            return np.zeros(0, np.float32)
        return np.concatenate(out)

    def streaming(self) -> bool:
        return self._current is not None and self._current not in self.ended
