"""A live session a voice agent drives, and what ``convodrive live`` runs: ``LiveSession``.

Every call is non-blocking and thread-safe (it copies and enqueues, or flips a flag); times are
``time.monotonic()`` seconds, None meaning now. Two modes:

- **player**: convodrive plays the agent's voice (``speaker``: an output device, or ``virtual``
  for none). The played voice is the master clock (``PlaybackClock``), the voice is queued
  ``self_lead`` ahead of the speaker so the generator hears it first, and the session tells the
  framework when each segment started and finished playing (``on_playback``). The voice is fed
  (``feed_self``) or read from a source (``voice``: a file, stdin, a socket: ``convodrive live``);
  with none (``voice="none"``) nothing plays and the clock is the monotonic clock.
- **follower**: the framework plays and reports when (``self_played``); the motion follows the
  voice ``delay`` seconds late (``follower``), on the monotonic clock.

The partner is fed (``feed_partner``) or comes from a microphone or a file (``partner``). The
generator, retargeting and backends run under the scheduler: its producer makes frames as both
voices' audio becomes known, a clock thread hands them out, each backend has its worker.
Conversation events reach the generator (``Generator.on_event``) on the run's time line: the
agent's at their playing time, the user's ``partner_delay`` later, as the user's audio. ``start``
runs it in a thread until ``close``; ``run`` runs it in the caller's until its inputs end.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from convodrive import FPS
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.generators.base import Event, Generator
from convodrive.pipeline.session.inputs import PushedPartner, QueuedVoice, Segment, as_mono
from convodrive.pipeline.session.playing import PlaybackReport
from convodrive.pipeline.session.running import SessionRequest, SessionRun
from convodrive.pipeline.session.sources import SELF_JITTER

USER_EVENTS = frozenset(
    {Event.USER_SPEECH_START, Event.USER_SPEECH_STOP, Event.USER_TURN_START, Event.USER_AWAY, Event.USER_BACK}
)
"""Events about the user: placed with the user's audio, ``partner_delay`` after they happened."""


class LiveSession(SessionRun):
    """See the module docstring; ``start`` (or ``open``) starts it, ``close`` ends it."""

    @classmethod
    def open(cls, generator: Generator | None = None, **request: Any) -> LiveSession:
        """``LiveSession(SessionRequest(**request), generator)``, started."""
        session = cls(SessionRequest(**request), generator)
        session.start()
        return session

    def _line_time(self, kind: Event, mono: float) -> float:
        """Where an event at ``mono`` belongs on the time line the generator sees."""
        t = self.time_at(mono)
        t = 0.0 if t is None else t
        if kind in USER_EVENTS or kind is Event.USER_TURN_END:
            return t + self.partner_delay
        return t if self.player else t + self.delay

    # -- the framework's calls ---------------------------------------------------------------------------
    def feed_partner(self, pcm: Any, rate: int, channels: int = 1, at: float | None = None) -> None:
        """The user's audio; ``at`` = capture time of its first sample (None: it just ended).
        Ignored when the partner comes from a device or a file."""
        if isinstance(self.partner, PushedPartner):
            data = as_mono(pcm, channels)
            captured = at if at is not None else time.monotonic() - len(data) / rate
            self.partner.push(data, int(rate), captured)

    def feed_self(self, pcm: Any, rate: int, segment: Segment = 0, channels: int = 1) -> None:
        """The agent's voice as soon as it exists (ahead of playing), by segment. Audio of a
        cleared segment is dropped."""
        data = as_mono(pcm, channels)
        if isinstance(self.voice, QueuedVoice):
            self.voice.feed(segment, data, int(rate))
        elif self.follower is not None:
            self.follower.feed(segment, data, int(rate))

    def end_self(self, segment: Segment = 0) -> None:
        """No more audio for ``segment`` (a flush)."""
        if isinstance(self.voice, QueuedVoice):
            self.voice.end(segment)
            self.tracker.ended(segment)
        elif self.follower is not None:
            self.follower.end(segment)

    def clear_self(self, at: float | None = None) -> None:
        """An interruption: everything not yet played is dropped, the mouth shuts; reports and audio
        of the segments known now are ignored from here on."""
        at = time.monotonic() if at is None else at
        with self._lock:
            voice, speaker, feeder = self.voice, self.speaker, self.feeder
            if isinstance(voice, QueuedVoice) and speaker is not None and feeder is not None:
                cut = feeder.cut(lambda: speaker.ring.read_pos + speaker.block, lambda _: voice.clear())
                self.tracker.cleared(voice, cut, speaker.rate, at)
            elif self.follower is not None:
                self.follower.clear()
                where = self.time_at(at)
                if where is not None:
                    self.self_line.blank(int((where + self.delay) * ANALYSIS_RATE))
        self.event(Event.INTERRUPTED, at)

    def pause_self(self, at: float | None = None) -> None:
        """Hold the agent's voice where it is (LiveKit's possible false interruption)."""
        at = time.monotonic() if at is None else at
        with self._lock:
            voice, speaker, feeder = self.voice, self.speaker, self.feeder
            if isinstance(voice, QueuedVoice) and speaker is not None and feeder is not None:
                feeder.cut(lambda: speaker.ring.read_pos + speaker.block, voice.hold)
            elif self.follower is not None:
                self.follower.pause(at)
        self.event(Event.PAUSED, at)

    def resume_self(self, at: float | None = None) -> None:
        at = time.monotonic() if at is None else at
        if isinstance(self.voice, QueuedVoice):
            self.voice.release()  # its next sample queued says SPEAKING_START, which ends the pause
        elif self.follower is not None:
            self.follower.resume(at)
            self.event(Event.RESUMED, at)

    def self_played(self, segment: Segment, offset: float, at: float | None = None) -> None:
        """Follower mode: sample ``offset`` seconds into ``segment`` left the speaker at ``at``."""
        if self.follower is None:
            return
        at = time.monotonic() if at is None else at
        if self.follower.played(segment, offset, at):
            where = self.time_at(at + self.request.output_latency)
            if where is not None:
                self.measures.fed_at(int((where + self.delay) * FPS), time.monotonic())

    def event(self, kind: Event, at: float | None = None, **info: Any) -> None:
        """A conversation event at monotonic time ``at`` (None: now)."""
        at = time.monotonic() if at is None else at
        self._post(kind, self._line_time(kind, at), info)

    def self_backlog(self) -> float:
        """Player mode: seconds of voice fed and not yet played (what pacing a writer looks at)."""
        if not isinstance(self.voice, QueuedVoice) or self.speaker is None:
            return 0.0
        return self.voice.queued_seconds() + self.speaker.ring.available() / self.speaker.rate

    @property
    def write_ahead(self) -> float:
        """Player mode: seconds of voice a writer paced to playing keeps fed ahead of the speaker:
        what the feeder keeps in the ring (``self_lead`` plus its jitter) and ``ahead`` spare, so a
        write that comes a little late leaves no gap of silence in the voice."""
        return self.self_lead + SELF_JITTER + self.request.ahead

    def on_playback(self, callback: Callable[[PlaybackReport], None]) -> None:
        """Player mode: ``callback`` hears when each segment starts and finishes playing (from the
        session's thread: hand it to your loop with ``call_soon_threadsafe``)."""
        self.tracker.listeners.append(callback)
