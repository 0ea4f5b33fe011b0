"""Follower mode: the framework plays the agent's voice and says when; convodrive places it.

A report ``played(segment, offset, at)`` says sample ``offset`` (seconds into the segment) left
the framework's speaker at monotonic time ``at``; later samples follow at the rate of real time
until the next report, a pause or a clear. The voice is placed on the run's time line at
``time_at(at + output_latency) + delay``: the motion follows the voice ``delay`` seconds late,
which leaves the generator its look-ahead even when the speech synthesiser is no faster than
real time. Where nothing plays, the line is filled with silence once it is ``grace`` seconds
overdue, so the generator never waits for a framework that says nothing.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from convodrive.audio.live.timeline import Timeline
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.pipeline.session.inputs import Segment, _Resamplers


class _Played:
    """One segment's audio at the analysis rate, and where its playing stands."""

    def __init__(self) -> None:
        self.parts: list[np.ndarray] = []
        self.length = 0
        self.anchor: tuple[float, float] | None = None
        """(offset in seconds, monotonic time it played); None while not playing."""
        self.ended = False
        self.held: float | None = None
        """The offset reached when a pause stopped it."""
        self.resample = _Resamplers(ANALYSIS_RATE)

    def audio(self, start: int, stop: int) -> np.ndarray:
        data = np.concatenate(self.parts) if len(self.parts) > 1 else (self.parts[0] if self.parts else np.zeros(0))
        self.parts = [data] if len(data) else []
        return data[max(start, 0) : max(stop, 0)].astype(np.float32)


class FollowedVoice:
    """Builds the self time line from fed audio and play reports; ``pump`` runs it forward."""

    def __init__(
        self,
        line: Timeline,
        time_at: Callable[[float], float | None],
        delay: float,
        grace: float,
        output_latency: float = 0.0,
    ) -> None:
        self.line = line
        self.time_at = time_at
        self.delay = delay
        self.grace = grace
        self.output_latency = output_latency
        self._lock = threading.Lock()
        self._segments: dict[Segment, _Played] = {}
        self.dead: set[Segment] = set()
        self.ignored_reports = 0
        self.placed = 0
        self.on_start: Callable[[Segment, float], None] | None = None
        """Called with a segment and its first sample's time-line position (seconds)."""

    def feed(self, segment: Segment, data: np.ndarray, rate: int) -> bool:
        with self._lock:
            if segment in self.dead:
                return False
            seg = self._segments.setdefault(segment, _Played())
            resampled, _ = seg.resample.push(data, rate)
            seg.parts.append(resampled)
            seg.length += len(resampled)
            return True

    def end(self, segment: Segment) -> None:
        with self._lock:
            seg = self._segments.get(segment)
            if seg is not None and not seg.ended:
                tail = seg.resample.finish()
                seg.parts.append(tail)
                seg.length += len(tail)
                seg.ended = True

    def played(self, segment: Segment, offset: float, at: float) -> bool:
        """A play report; False (and ignored) for a cleared or unknown segment."""
        with self._lock:
            seg = self._segments.get(segment)
            if seg is None or segment in self.dead:
                self.ignored_reports += 1
                return False
            first = seg.anchor is None
            seg.anchor = (offset, at)
        if first and self.on_start is not None:
            where = self.time_at(at + self.output_latency)
            if where is not None:
                self.on_start(segment, where + self.delay)
        return True

    def pause(self, at: float) -> None:
        """Stop the playing segments where they are at ``at``."""
        with self._lock:
            for seg in self._segments.values():
                if seg.anchor is not None:
                    offset, since = seg.anchor
                    seg.held, seg.anchor = offset + max(at - since, 0.0), None

    def resume(self, at: float) -> None:
        """Go on from where the pause stopped them, at ``at`` (a report may correct it)."""
        with self._lock:
            for seg in self._segments.values():
                if seg.held is not None:
                    seg.anchor, seg.held = (seg.held, at), None

    def clear(self) -> set[Segment]:
        with self._lock:
            known = set(self._segments)
            self.dead |= known
            self._segments.clear()
            return known

    def pump(self, now: float) -> None:
        """Place what is known up to where it is due, and silence where nothing plays."""
        t = self.time_at(now)
        if t is None:
            return
        due = int(round((t + self.delay - self.grace) * ANALYSIS_RATE))
        with self._lock:
            playing = [(s, seg) for s, seg in self._segments.items() if seg.anchor is not None]
            while True:
                end = self.line.end
                mono = now + (end / ANALYSIS_RATE - (t + self.delay)) - self.output_latency
                placed = False
                for _, seg in playing:
                    offset, at = seg.anchor  # type: ignore[misc]
                    x = int(round((offset + mono - at) * ANALYSIS_RATE))
                    if 0 <= x < seg.length:
                        data = seg.audio(x, seg.length)
                        self.line.append(data)
                        self.placed += len(data)
                        placed = True
                        break
                if not placed:
                    break
            for s, seg in playing:
                offset, at = seg.anchor  # type: ignore[misc]
                if seg.ended and (offset + now - at) * ANALYSIS_RATE >= seg.length:
                    del self._segments[s]
        self.line.fill_to(due)

    def report(self) -> dict[str, Any]:
        return {
            "delay_ms": round(1000.0 * self.delay, 1),
            "placed_seconds": round(self.placed / ANALYSIS_RATE, 3),
            "ignored_play_reports": self.ignored_reports,
        }
