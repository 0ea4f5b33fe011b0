"""Both voices on the run's time line, chunked for the generator.

The self voice arrives ahead of time (``self_voice``: the feeder queues it before the speaker
plays it). The partner's voice can only arrive after it was spoken, so it is placed
``partner_delay`` seconds after its capture time: a partner sample captured when the run's clock
read t sits at t + ``partner_delay`` on the time line, which leaves the generator its look-ahead
of the partner too. That delay is the partner's capture-to-motion latency, and the report measures
it. Placing by capture time (rather than by counting samples) keeps the two voices aligned when
the microphone's sample clock drifts from the speaker's: a block that lands more than
``RESYNC_SECONDS`` off is realigned (a gap filled with silence, or an overlap dropped) and counted.

A chunk is everything both voices have up to now, so the generator never waits longer than the
partner's latest block. Partner audio that has not arrived ``grace`` seconds after it was captured
(a late callback, a microphone that went away) becomes silence, so the clock never waits either.

How late audio arrives depends on the device and the load. A block that comes after its span was
filled is a *late block*: its overdue part is dropped, the silence stays, and both are counted
(``late_blocks``, ``late_ms``), so a late block costs a few milliseconds of partner audio, never
latency. Only a device that is late most of the time moves the partner delay (an audio server
that hands a microphone over in 20 ms bursts, an idle monitor held back 200 ms): ``grace`` (and
with it the delay) rises to cover the 90th percentile of a typical second's arrival ages (the
median over the last ``AGE_SECONDS`` seconds of each second's 90th percentile), so late blocks
here and there and a stall of the whole process (which makes every frame late anyway) do not
move it; it falls back 5 ms at a time when ``DECAY_SECONDS`` in a row needed 10 ms less. The
input's first second, where servers deliver erratically, is not counted. Each change moves the
partner's time line (a resync).
"""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from convodrive.audio.features import frame_edge
from convodrive.audio.live.capture import PartnerInput
from convodrive.audio.live.timeline import Timeline
from convodrive.audio.source import ANALYSIS_RATE, AudioChunk
from convodrive.plumbing.stats import Histogram

RESYNC_SECONDS = 0.01
POLL_SECONDS = 0.002
SETTLE_SECONDS = 1.0
"""Arrival ages in the input's first second do not move the partner delay (start-up bursts)."""
AGE_SECONDS = 10
AGE_QUANTILE = 90.0
"""Grace covers this percentile of a second's arrival ages; later blocks are filled, not waited for."""
MAX_GRACE = 1.0
DECAY_SECONDS = 10.0
STEP = 0.005


class LiveAudio:
    """Yields ``AudioChunk``s of both voices as they become known; see the module docstring.

    ``time_at(mono)`` is the run's clock at monotonic time ``mono`` (None before the clock runs);
    ``self_end()`` the time-line position where a finite self voice ended (None while it goes on);
    ``self_failed()`` why the self voice stopped for good part-way (None while it works), which,
    like the partner's ``failed``, ends the run by raising it from ``chunks``; ``self_absent``:
    there is no self voice (``--self none``), so its end ends nothing; ``stop_at`` seconds end
    the run early (``--seconds``); ``monotonic`` is the clock capture times are on.
    """

    def __init__(
        self,
        self_voice: Timeline,
        self_end: Callable[[], int | None],
        partner: PartnerInput,
        time_at: Callable[[float], float | None],
        partner_delay: float,
        grace: float,
        stop_at: float | None = None,
        monotonic: Callable[[], float] = time.monotonic,
        self_failed: Callable[[], Exception | None] = lambda: None,
        self_absent: bool = False,
    ) -> None:
        self.self_voice = self_voice
        self.self_end = self_end
        self.self_failed = self_failed
        self.self_absent = self_absent
        self.partner = partner
        self.time_at = time_at
        self.partner_delay = partner_delay
        self.grace = grace
        self.initial_delay = partner_delay
        self.base_grace = grace
        self.monotonic = monotonic
        self._typical: collections.deque[float] = collections.deque(maxlen=AGE_SECONDS)
        """The ``AGE_QUANTILE`` percentile of arrival ages in each of the last seconds."""
        self._second = -1
        self._second_ages: list[float] = []
        self._first_block: float | None = None
        self._changed = 0.0
        self.stop_at = None if stop_at is None else int(round(stop_at * ANALYSIS_RATE))
        self.partner_line = Timeline()
        self.partner_line.fill_to(self._samples(partner_delay))  # nothing was captured before time 0
        self.frame_capture: dict[int, float] = {}
        """Frame index -> monotonic time its first partner sample was captured."""
        self.age_ms = Histogram()
        """From capturing a block's first sample to handing the block on."""
        self.resyncs = 0
        self.delay_changes = 0
        self.late_samples = 0
        """Partner samples filled with silence because they had not arrived in time."""
        self.late_blocks = 0
        """Blocks that arrived after (part of) their span was filled."""
        self.late_dropped = 0
        """Samples of late blocks dropped: their span holds silence already."""
        self._late_fill = 0
        """Samples of silence at the line's end filled for audio that had not arrived."""
        self._moved = False
        """The partner delay changed: the next block is placed exactly where it now belongs."""
        self.dropped_early = 0
        self.events: list[dict[str, Any]] = []
        self._lost_reason: str | None = None
        self.losses = 0
        self._partner_end: int | None = None
        self._stopped = False
        self._next_frame = 0

    @staticmethod
    def _samples(seconds: float) -> int:
        return int(round(seconds * ANALYSIS_RATE))

    def stop(self) -> None:
        self._stopped = True

    def chunks(self) -> Iterator[AudioChunk]:
        while not self._stopped:
            chunk = self.poll()
            if chunk is None:
                time.sleep(POLL_SECONDS)
                continue
            if chunk.final:  # nothing more is pulled: a microphone left open would overrun its ring
                self.partner.close()
            yield chunk
            if chunk.final:
                return

    def poll(self) -> AudioChunk | None:
        """Take what the partner delivered; the chunk both voices have ready, or None. Raises
        why an input stopped for good part-way (a file that stopped decoding)."""
        self._take_partner()
        error = self.partner.failed() or self.self_failed()
        if error is not None:
            raise error
        end = self._end()
        ready = self.self_voice.end
        if self._partner_silent():
            self.partner_line.fill_to(ready)
        ready = min(ready, self.partner_line.end)
        if end is not None:
            ready = min(ready, end)
            if self.partner_line.end < end and self._partner_end is not None:
                self.partner_line.fill_to(end)
        position = self.partner_line.taken
        if ready <= position:
            if end is not None and position >= end:  # handed over to the end before the end was known
                empty = np.zeros(0, np.float32)
                return AudioChunk(position, empty, empty, final=True)
            return None
        final = end is not None and ready >= end
        return AudioChunk(position, self.self_voice.take(ready), self.partner_line.take(ready), final=final)

    # -- the partner -----------------------------------------------------------------------------
    def _partner_silent(self) -> bool:
        """From here on the partner is silence: it ended, or it went away."""
        return self._partner_end is not None or self._lost()

    def _lost(self) -> bool:
        reason = self.partner.lost()
        if reason != self._lost_reason:
            if reason is not None:
                self.losses += 1
                self._late_fill = 0  # the silence from here on is the loss's, not late audio's
                self._event(f"partner input lost: {reason}; the partner is silent until it comes back")
            else:
                self._moved = True  # its next block goes exactly where it belongs, over the silence
                self._event("partner input back: its audio is heard again")
            self._lost_reason = reason
        return self._lost_reason is not None

    def _take_partner(self) -> None:
        for data, captured in self.partner.pull():
            if self._lost_reason is not None:  # heard as silence while it is lost, whatever it sends
                continue
            self._note_age(self.monotonic() - captured)
            at = self.time_at(captured)
            if at is None or at < 0:  # before time 0: the time line's start is silence already
                self.dropped_early += len(data)
                continue
            self._place(data, captured, self._samples(at + self.partner_delay))
        if self._partner_end is None and self.partner.ended():
            self._partner_end = self.partner_line.end
        self._fill_late()

    def _note_age(self, age: float) -> None:
        """Move ``grace`` (and the partner delay) to fit how late blocks typically arrive."""
        self.age_ms.add(1000.0 * age)
        now = self.monotonic()
        if self._first_block is None:
            self._first_block = now
        if now - self._first_block < SETTLE_SECONDS:
            return
        second = int(now - self._first_block)
        if second == self._second:
            self._second_ages.append(age)
            return
        if self._second_ages:
            self._typical.append(float(np.percentile(self._second_ages, AGE_QUANTILE)))
        self._second, self._second_ages = second, [age]
        if len(self._typical) < 3:
            return
        needed = min(float(np.median(self._typical)), MAX_GRACE)
        if needed > self.grace + 1e-9:
            self._set_grace(self.grace + math.ceil((needed - self.grace) / STEP - 1e-9) * STEP, needed, now)
        elif now - self._changed > DECAY_SECONDS and self.grace - STEP >= max(needed + STEP, self.base_grace) - 1e-9:
            self._set_grace(self.grace - STEP, needed, now)

    def _set_grace(self, grace: float, needed: float, now: float) -> None:
        self.partner_delay += grace - self.grace
        self.grace = grace
        self._moved = True
        self._changed = now
        self.delay_changes += 1
        self._event(
            f"partner audio typically arrives up to {1000 * needed:.0f} ms after capture: "
            f"partner delay now {1000 * self.partner_delay:.0f} ms"
        )

    def _place(self, data: np.ndarray, captured: float, target: int) -> None:
        line = self.partner_line
        off = target - line.end
        if off < 0 and self._late_fill:  # a late block: its head's span was filled already
            cut = min(-off, len(data))
            self.late_blocks += 1
            self.late_dropped += cut
            data = data[cut:]
            captured += cut / ANALYSIS_RATE
            off += cut
            if not len(data):
                return
        if abs(off) > self._samples(RESYNC_SECONDS) or (off and self._moved):
            if off > 0:
                line.fill_to(target)
            else:
                data = data[-off:]
                captured -= off / ANALYSIS_RATE
            if not len(data):  # wholly behind the line: the realignment happens with a later block
                return
            self.resyncs += 1
        if not len(data):
            return
        start = line.end
        while frame_edge(self._next_frame) < start:
            self._next_frame += 1
        while frame_edge(self._next_frame) < start + len(data):
            edge = int(frame_edge(self._next_frame))
            self.frame_capture[self._next_frame] = captured + (edge - start) / ANALYSIS_RATE
            self.frame_capture.pop(self._next_frame - 300, None)
            self._next_frame += 1
        line.append(data)
        self._late_fill = 0
        self._moved = False

    def _fill_late(self) -> None:
        """Partner audio overdue by ``grace`` becomes silence, so the generator never waits on it."""
        if self._partner_end is not None:
            return
        now = self.time_at(self.monotonic())
        if now is None:
            return
        due = self._samples(now + self.partner_delay - self.grace)
        filled = self.partner_line.fill_to(due)
        if filled and not self._lost():
            self.late_samples += filled
            self._late_fill += filled

    def _end(self) -> int | None:
        """Where the run's audio ends: once every input there is has ended, or at ``stop_at``
        (with neither input, only there)."""
        inputs = [(self.self_absent, self.self_end()), (self.partner.absent, self._partner_end)]
        present = [end for absent, end in inputs if not absent]
        ends = None
        if present and all(end is not None for end in present):
            ends = max(end for end in present if end is not None)
        if self.stop_at is not None:
            ends = self.stop_at if ends is None else min(ends, self.stop_at)
        return ends

    def _event(self, text: str) -> None:
        now = self.time_at(self.monotonic())
        self.events.append({"time": round(now, 3) if now is not None else None, "event": text})

    def report(self) -> dict[str, Any]:
        return {
            "partner_delay_ms": round(1000.0 * self.partner_delay, 1),
            "initial_partner_delay_ms": round(1000.0 * self.initial_delay, 1),
            "partner_delay_changes": self.delay_changes,
            "capture_to_available_ms": self.age_ms.summary(),
            "resyncs": self.resyncs,
            "late_blocks": self.late_blocks,
            "late_ms": round(1000.0 * self.late_samples / ANALYSIS_RATE, 1),
            "late_dropped_ms": round(1000.0 * self.late_dropped / ANALYSIS_RATE, 1),
            "before_start_ms": round(1000.0 * self.dropped_early / ANALYSIS_RATE, 1),
            "lost": self._lost_reason,
            "losses": self.losses,
            "events": self.events,
        }
