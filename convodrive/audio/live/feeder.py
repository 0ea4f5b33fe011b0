"""The thread that keeps the robot's own voice queued ahead of the speaker.

``SelfVoiceFeeder`` moves the voice into the playback ring and, at the same moment, into the
analysis time line the generator reads, so the generator always sees the voice ``lead`` seconds
before the speaker plays it: the self voice is delayed by the generator's look-ahead. When the
source has nothing (an agent between sentences, a stream that stopped mid-sentence) the feeder
queues silence instead, so the speaker, the clock and the generator go on, and the mouth closes.
An interruption silences what is queued (``cut``) in one step with the feeder's reading and
queueing, so voice read just before it can never land after the blank.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from convodrive.audio.live.ring import SampleRing
from convodrive.audio.live.self_voice import NoVoice, VoiceSource
from convodrive.audio.live.timeline import Timeline
from convodrive.audio.resample import StreamResampler
from convodrive.audio.source import ANALYSIS_RATE

READ_SECONDS = 0.02
"""The most the feeder reads from a source at once."""
POLL_SECONDS = 0.005


class SelfVoiceFeeder(threading.Thread):
    """Keeps the voice queued ``lead`` to ``lead + jitter`` seconds ahead of the speaker.

    ``heard`` gives the position (in ring samples) the speaker has reached, or its stand-in when
    nothing is played (``--self none``). Whatever goes into the ``ring`` also goes, resampled, into
    ``analysis``; without a ring only the analysis time line advances. ``speaker_stopped`` says why
    the speaker was given up (``Playback.stopped``): from then on the voice is paced by the clock
    and goes to the analysis alone, so the mouth and the run go on without it.
    """

    def __init__(
        self,
        source: VoiceSource,
        ring: SampleRing | None,
        rate: int,
        analysis: Timeline,
        heard: Callable[[], int],
        lead: float,
        jitter: float,
        clock_now: Callable[[], float],
        speaker_stopped: Callable[[], str | None] | None = None,
    ) -> None:
        super().__init__(name="self-voice", daemon=True)
        self.source = source
        self.ring = ring
        self.rate = rate
        self.analysis = analysis
        self.heard = heard
        self.low_water = int(round(lead * rate))
        self.high_water = int(round((lead + jitter) * rate))
        self.clock_now = clock_now
        self.speaker_stopped = speaker_stopped
        self.speaker_lost = False
        self.unheard_samples = 0
        """Voice queued after the speaker was given up: the analysis had it, nobody heard it."""
        self._to_ring = StreamResampler(source.rate, rate) if source.rate != rate else None
        self._to_analysis = StreamResampler(rate, ANALYSIS_RATE)
        self._pending = np.zeros(0, np.float32)
        self._halt = threading.Event()
        self.written = 0
        """Ring samples queued so far (voice and silence)."""
        self.voice_samples = 0
        self.ended_at: int | None = None
        """Ring position where a finite voice ended."""
        self.stalls = 0
        self.stalled_samples = 0
        self._stalled = False
        self._stall_len = 0
        self._voice_last = False
        """The last thing queued was voice (not silence)."""
        self.events: list[dict[str, Any]] = []
        self.error: BaseException | None = None
        self._lock = threading.Lock()
        """Held while the feeder reads and queues, and by ``cut``: a read and its queueing are one
        step, so voice read before a cut is queued before its blank, never after it."""

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        try:
            while not self._halt.is_set():
                with self._lock:
                    got = self._step()
                if not got:
                    time.sleep(POLL_SECONDS)  # plenty queued, or nothing came just now
        except BaseException as exc:  # handed to the pipeline, which reports it
            self.error = exc
            self._event(f"self voice failed: {exc.__class__.__name__}: {exc}")
            while not self._halt.wait(POLL_SECONDS):  # the speaker and the clock go on, silent
                with self._lock:
                    self._top_up(stall=False)
        finally:
            self.source.close()

    def cut(self, where: Callable[[], int], take_back: Callable[[int], object]) -> int:
        """An interruption or a pause from ring position ``where()`` (the speaker's next block),
        read once the feeder is out of the way, so a wait here cannot leave it behind the speaker:
        ``take_back(position)`` takes the voice the source still holds (``QueuedVoice.clear`` or
        ``hold``), then what is queued from there on is silenced, in the ring and in the analysis
        (voice the generator must not hear). The feeder's reading and queueing cannot come
        between: voice it read before the cut is already queued (and blanked here), and what is
        left over queues only up to the position, which is returned."""
        with self._lock:
            position = where()
            take_back(position)
            self._pending = self._pending[: max(position - self.written, 0)]
            if self.ring is not None:
                self.ring.blank(position)
            written = -(-self.written * ANALYSIS_RATE // self.rate)  # the analysis of all queued so far
            self.analysis.blank(position * ANALYSIS_RATE // self.rate, written)
            return position

    def _step(self) -> bool:
        """Read and queue once, without waiting; False when nothing came (the caller waits)."""
        if self.ring is not None and self.speaker_stopped is not None:
            reason = self.speaker_stopped()
            if reason is not None:
                self._lose_speaker(reason)
        if len(self._pending):  # the ring was full last time: offer the rest first
            self._commit(np.zeros(0, np.float32))
        if self.ended_at is not None or len(self._pending) or self._space() <= 0:
            self._top_up(stall=False)
            return False
        want = max(1, min(self._space(), int(READ_SECONDS * self.rate)) * self.source.rate // self.rate)
        data = self.source.read(want, 0.0)
        for text in self.source.events():
            self._event(text)
        if data is None:
            self._end()
        elif len(data):
            self._voice(data)
            return True
        self._top_up(stall=self.ended_at is None)  # the source had nothing just now
        return False

    def _lose_speaker(self, reason: str) -> None:
        """Pace the voice by the clock from now on; the ring (and what it still holds) is left."""
        self.ring = None
        self.speaker_lost = True
        self.heard = lambda: int(max(self.clock_now(), 0.0) * self.rate)
        self._event(f"{reason}: the self voice goes on unheard, paced by the clock")

    def _space(self) -> int:
        if self.ring is None:
            return max(self.heard() + self.high_water - self.written, 0)
        return self.ring.space()

    def _voice(self, data: np.ndarray) -> None:
        if self._to_ring is not None:
            data = self._to_ring.push(data)
        if self._stalled:
            self._stalled = False
            self._event(f"self voice resumed after {1000.0 * self._stall_len / self.rate:.0f} ms of silence")
        self._voice_last = True
        self.voice_samples += len(data)
        if self.speaker_lost:
            self.unheard_samples += len(data)
        self._commit(data)

    def _end(self) -> None:
        if self._to_ring is not None:
            self._commit(self._to_ring.finish())
        self.ended_at = self.written + len(self._pending)
        if not isinstance(self.source, NoVoice):
            self._event("self voice ended")

    def _top_up(self, stall: bool) -> None:
        """Queue silence when the voice runs low, so the speaker and the generator never wait."""
        level = self.written + len(self._pending) - self.heard()
        if level >= self.low_water:
            return
        fill = self.high_water - level
        if self._stalled and not self.source.streaming():
            self._stalled = False  # the speaker hung up: this silence is nobody's stall
        if stall and self.source.streaming() and self._voice_last:
            self.stalls += 1  # the speaker is connected but its voice ran out, mid-sentence or not
            self._stalled, self._stall_len = True, 0
            self._event("self voice ran out while its speaker is connected: silence until more comes")
        if self._stalled:
            self._stall_len += fill
            self.stalled_samples += fill
        self._voice_last = False
        self._commit(np.zeros(fill, np.float32))

    def _commit(self, new: np.ndarray) -> None:
        """Queue ``new`` after anything left over; what the ring cannot take yet waits."""
        data = np.concatenate([self._pending, new]) if len(self._pending) else new
        used = self.ring.write(data) if self.ring is not None else len(data)
        self._pending = data[used:]
        self.written += used
        self.analysis.append(self._to_analysis.push(data[:used]))

    def _event(self, text: str) -> None:
        self.events.append({"time": round(self.clock_now(), 3), "event": text})

    def report(self) -> dict[str, Any]:
        return {
            "source": self.source.describe,
            "sample_rate": self.source.rate,
            "voice_seconds": round(self.voice_samples / self.rate, 3),
            "lead_ms": round(1000.0 * self.low_water / self.rate, 1),
            "queued_ms": round(1000.0 * self.high_water / self.rate, 1),
            "stalls": self.stalls,
            "stalled_ms": round(1000.0 * self.stalled_samples / self.rate, 1),
            "unheard_ms": round(1000.0 * self.unheard_samples / self.rate, 1),
            "events": self.events,
        }
