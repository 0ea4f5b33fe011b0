"""Player mode: when each segment of the agent's voice started and finished playing, told back to
the framework (LiveKit's ``on_playback_started`` / ``on_playback_finished``, Pipecat's pacing)."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from typing import Any

from convodrive.pipeline.session.inputs import QueuedVoice, Segment


@dataclasses.dataclass(frozen=True)
class PlaybackReport:
    kind: str
    """``started`` or ``finished``."""
    segment: Segment
    position: float
    """Seconds of the segment played (0 at ``started``)."""
    interrupted: bool
    at: float
    """Monotonic time the speaker played the segment's first sample (``started``), its last
    (``finished``), or when it was cleared (interrupted)."""


class PlaybackTracker:
    """Watches the speaker's position against where each segment went in the ring."""

    def __init__(self) -> None:
        self.listeners: list[Callable[[PlaybackReport], None]] = []
        self._lock = threading.Lock()
        self._first: dict[Segment, int] = {}
        self._started: set[Segment] = set()
        self._ended: set[Segment] = set()

    def queued(self, segment: Segment, position: int) -> None:
        with self._lock:
            self._first.setdefault(segment, position)

    def ended(self, segment: Segment) -> None:
        with self._lock:
            self._ended.add(segment)

    def poll(
        self, voice: QueuedVoice, played: int, rate: int, at_of: Callable[[int], float]
    ) -> list[tuple[Segment, int]]:
        """Report what started and finished by ring position ``played`` (what has left the
        speaker), each at ``at_of(ring position)``: the monotonic time that sample left it, however
        late this poll runs. Return the finished segments with the ring position of their end."""
        last: dict[Segment, int] = {}
        for segment, pos, _, data, _ in list(voice.marks):
            last[segment] = max(last.get(segment, 0), pos + len(data))
        reports, done = [], []
        with self._lock:
            for segment, first in list(self._first.items()):
                if segment not in self._started and played >= first:
                    self._started.add(segment)
                    reports.append(PlaybackReport("started", segment, 0.0, False, at_of(first)))
                end = last.get(segment)
                if segment in voice.ended and segment in self._ended and end is not None and played >= end:
                    position = _position(voice, segment, end) / rate
                    reports.append(PlaybackReport("finished", segment, position, False, at_of(end)))
                    done.append((segment, end))
                    del self._first[segment]
                    self._started.discard(segment)
        self._tell(reports)
        return done

    def cleared(self, voice: QueuedVoice, cut: int, rate: int, at: float) -> None:
        """An interruption at ``at``: the playing segments finished, interrupted, with what plays
        of them before ring position ``cut``."""
        with self._lock:
            reports = [PlaybackReport("finished", s, _position(voice, s, cut) / rate, True, at) for s in self._first]
            self._first.clear()
            self._started.clear()
        self._tell(reports)

    def _tell(self, reports: list[PlaybackReport]) -> None:
        for report in reports:
            for listener in list(self.listeners):
                listener(report)

    def report(self) -> dict[str, Any]:
        return {"segments_playing": len(self._first)}


def _position(voice: QueuedVoice, segment: Segment, upto: int) -> int:
    """Samples of ``segment``'s own audio queued before ring position ``upto``: silence the
    feeder queued between its parts (a voice that came slower than it plays) is not the
    segment's, so it does not count."""
    best = 0
    for s, pos, offset, data, _ in list(voice.marks):
        if s == segment and pos < upto:
            best = max(best, offset + min(upto - pos, len(data)))
    return best
