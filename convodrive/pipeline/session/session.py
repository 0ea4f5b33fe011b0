"""A live session a voice agent drives: the library form of ``convodrive live``.

Every call is non-blocking and thread-safe (it copies and enqueues, or flips a flag); times are
``time.monotonic()`` seconds, None meaning now. Two modes:

- **player**: convodrive plays the agent's voice (``speaker``: an output device, or ``virtual``
  for none). The played voice is the master clock (``PlaybackClock``), the voice is queued
  ``self_lead`` ahead of the speaker so the generator hears it first, and the session tells the
  framework when each segment started and finished playing (``on_playback``).
- **follower**: the framework plays and reports when (``self_played``); the motion follows the
  voice ``delay`` seconds late (``follower``), on the monotonic clock.

The generator, retargeting and backends run as in ``convodrive live``: the scheduler's producer
makes frames as both voices' audio becomes known, a clock thread hands them out, each backend has
its worker. Conversation events reach the generator (``Generator.on_event``) on the run's time
line: the agent's at their playing time, the user's ``partner_delay`` later, as the user's audio.
"""

from __future__ import annotations

import collections
import dataclasses
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from convodrive import FPS
from convodrive.audio.live.assembler import LiveAudio
from convodrive.audio.live.devices import find_device
from convodrive.audio.live.feeder import SelfVoiceFeeder
from convodrive.audio.live.playback import Playback
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.backends.base import Session
from convodrive.generators.base import ConversationEvent, Event, Generator
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.targets import TargetFrame
from convodrive.pipeline.backends import close_all, make_backends, open_backends, run_in_own_processes
from convodrive.pipeline.config import load_run_config
from convodrive.pipeline.live_run import GENERATION_MARGIN, PARTNER_GRACE, RING_SPARE, SELF_JITTER, SELF_MARGIN
from convodrive.pipeline.run import DEFAULT_GENERATOR, DriveResult, make_generator
from convodrive.pipeline.session.follower import FollowedVoice
from convodrive.pipeline.session.inputs import (
    ClearableTimeline,
    PushedPartner,
    QueuedVoice,
    Segment,
    as_mono,
    blank_ring,
)
from convodrive.pipeline.session.playing import PlaybackReport, PlaybackTracker
from convodrive.pipeline.session.speaker import VirtualSpeaker
from convodrive.plumbing.errors import UserError
from convodrive.plumbing.stats import Histogram
from convodrive.scheduler import Clock, MonotonicClock, PlaybackClock, Scheduler, build_report, write_report

USER_EVENTS = frozenset(
    {Event.USER_SPEECH_START, Event.USER_SPEECH_STOP, Event.USER_TURN_START, Event.USER_AWAY, Event.USER_BACK}
)
"""Events about the user: placed with the user's audio, ``partner_delay`` after they happened."""
PUMP_SECONDS = 0.005


@dataclasses.dataclass
class SessionRequest:
    mode: str = "player"
    """``player`` (convodrive plays the voice) or ``follower`` (the framework plays it)."""
    generator: str = DEFAULT_GENERATOR
    backends: tuple[str, ...] = ("record",)
    config: str | Path | None = None
    out_dir: Path = Path("convodrive-out")
    seed: int = 0
    generator_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    backend_options: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    speaker: str = "virtual"
    """Player mode: an output device (name, index, ``default``), or ``virtual`` (no sound card)."""
    self_rate: int = 24000
    play_latency: float | str = 0.1
    ahead: float = 0.1
    """Player mode: seconds of voice queued in the speaker's ring beyond the look-ahead; the rest
    waits where a clear drops it at no cost."""
    delay: float | None = None
    """Follower mode: how late the motion follows the played voice (default: the generator's
    look-ahead plus the partner's grace and a generation margin)."""
    output_latency: float = 0.0
    """Seconds from a framework's "played" to the sound (network, jitter buffer, device)."""


class LiveSession:
    """See the module docstring; ``start`` (or ``open``) starts it, ``close`` ends it."""

    def __init__(self, request: SessionRequest, generator: Generator | None = None) -> None:
        if request.mode not in ("player", "follower"):
            raise UserError(f"mode must be 'player' or 'follower', got {request.mode!r}")
        if not request.backends:
            raise UserError("name at least one backend")
        self.request = request
        self.config = load_run_config(request.config)
        if generator is None:
            generator, _ = make_generator(request.generator, self.config, request.generator_options, live=True)
        self.generator = generator
        need = generator.lookahead_seconds
        self.self_lead = need + SELF_MARGIN
        self.partner_delay = need + PARTNER_GRACE + GENERATION_MARGIN
        self.delay = request.delay if request.delay is not None else self.partner_delay
        if request.mode == "follower" and self.delay < need:
            raise UserError(f"delay {self.delay:g} s is below the generator's look-ahead {need:g} s")
        self.player = request.mode == "player"
        self._lock = threading.Lock()
        self._started = False
        self._closed = False
        self.partner = PushedPartner()
        self.self_line = ClearableTimeline()
        self.speaker: Playback | VirtualSpeaker | None = None
        self.voice: QueuedVoice | None = None
        self.feeder: SelfVoiceFeeder | None = None
        self.follower: FollowedVoice | None = None
        self.clock: Clock = MonotonicClock()
        self.tracker = PlaybackTracker()
        self.events: list[tuple[float, ConversationEvent]] = []
        """(monotonic time sent, event), in the order sent: what the generator was told."""
        self.frames: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=FPS * 600)
        """(frame index, monotonic dispatch time, jawOpen) of the last ten minutes' frames."""
        self._jaw: dict[int, float] = {}
        self._fed: dict[int, float] = {}
        self.fed_to_sent: dict[str, Histogram] = {}
        self.capture_to_sent: dict[str, Histogram] = {}
        self._thread: threading.Thread | None = None
        self._pump = threading.Thread(target=self._pump_loop, name="live-session", daemon=True)
        self._halt = threading.Event()
        self.result: DriveResult | None = None
        self.error: BaseException | None = None

    @classmethod
    def open(cls, generator: Generator | None = None, **request: Any) -> LiveSession:
        """``LiveSession(SessionRequest(**request), generator)``, started."""
        session = cls(SessionRequest(**request), generator)
        session.start()
        return session

    # -- starting ------------------------------------------------------------------------------------
    def start(self) -> None:
        """Open the speaker and the backends (a ``UserError`` names what is wrong), start the run."""
        request = self.request
        planned = make_backends(request.backends, self.config, request.backend_options)
        run_in_own_processes(planned)
        self._open_audio()
        out_dir = Path(request.out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        session = Session(out_dir=out_dir, fps=FPS, offline=False, seed=request.seed)
        try:
            routes, failed = open_backends(planned, session)
        except BaseException:
            self._close_audio()
            raise
        self._failed_at_open = failed
        self._hardware = [p.name for p in planned if p.backend.hardware]
        self._routes = routes
        self.audio = LiveAudio(
            self.self_line, lambda: None, self.partner, self.time_at, self.partner_delay, PARTNER_GRACE
        )
        try:
            if self.feeder is not None:
                self.feeder.start()
            self.scheduler = Scheduler(
                self._frames(self.generator.stream_takes(self.audio.chunks(), [request.seed])),
                routes,
                clock=self.clock,
                on_frame=self._dispatched,
                on_start=self._clock_started,
                on_sent=self._sent,
            )
        except BaseException:
            close_all(routes)
            self._close_audio()
            raise
        self._thread = threading.Thread(target=self._run, name="live-run", daemon=True)
        self._thread.start()
        self._pump.start()

    def _open_audio(self) -> None:
        request = self.request
        if not self.player:
            self.self_line.fill_to(int(round(self.delay * ANALYSIS_RATE)))  # nothing played before time 0
            self.follower = FollowedVoice(
                self.self_line, self.time_at, self.delay, PARTNER_GRACE, request.output_latency
            )
            self.follower.on_start = lambda segment, at: self._post(Event.SPEAKING_START, at, {"segment": segment})
            return
        ring_seconds = self.self_lead + SELF_JITTER + request.ahead + RING_SPARE
        if request.speaker == "virtual":
            self.speaker = VirtualSpeaker(request.self_rate, ring_seconds, latency=request.output_latency)
        else:
            device = find_device(request.speaker, "output", "speaker")
            self.speaker = Playback(device, request.self_rate, ring_seconds, request.play_latency)
        speaker = self.speaker
        self.clock = PlaybackClock(speaker)
        ahead = self.self_lead + SELF_JITTER + request.ahead
        self.voice = QueuedVoice(speaker.rate, speaker.ring, ahead, self._segment_queued, self._queued)
        self.feeder = SelfVoiceFeeder(
            self.voice,
            speaker.ring,
            speaker.rate,
            self.self_line,
            heard=speaker.played,
            lead=self.self_lead,
            jitter=SELF_JITTER,
            clock_now=lambda: self.clock.now() if self._started else 0.0,
            speaker_stopped=speaker.stopped,
        )

    def _run(self) -> None:
        try:
            self._result = self.scheduler.run()
        except BaseException as exc:  # handed to close(), which raises it
            self.error = exc

    def _clock_started(self) -> None:
        self._started = True

    # -- the clock -------------------------------------------------------------------------------------
    def time_at(self, mono: float) -> float | None:
        """The run's clock (seconds, the frames' time line) at monotonic time ``mono``; None
        before it runs."""
        if not self._started:
            return None
        if self.speaker is not None:
            return self.speaker.position_at(mono)
        return self.clock.now() - (time.monotonic() - mono)

    def _line_time(self, kind: Event, mono: float) -> float:
        """Where an event at ``mono`` belongs on the time line the generator sees."""
        t = self.time_at(mono)
        t = 0.0 if t is None else t
        if kind in USER_EVENTS or kind is Event.USER_TURN_END:
            return t + self.partner_delay
        return t if self.player else t + self.delay

    # -- the framework's calls ---------------------------------------------------------------------------
    def feed_partner(self, pcm: Any, rate: int, channels: int = 1, at: float | None = None) -> None:
        """The user's audio; ``at`` = capture time of its first sample (None: it just ended)."""
        data = as_mono(pcm, channels)
        captured = at if at is not None else time.monotonic() - len(data) / rate
        self.partner.push(data, int(rate), captured)

    def feed_self(self, pcm: Any, rate: int, segment: Segment = 0, channels: int = 1) -> None:
        """The agent's voice as soon as it exists (ahead of playing), by segment. Audio of a
        cleared segment is dropped."""
        data = as_mono(pcm, channels)
        if self.voice is not None:
            self.voice.feed(segment, data, int(rate))
        elif self.follower is not None:
            self.follower.feed(segment, data, int(rate))

    def end_self(self, segment: Segment = 0) -> None:
        """No more audio for ``segment`` (a flush)."""
        if self.voice is not None:
            self.voice.end(segment)
            self.tracker.ended(segment)
        elif self.follower is not None:
            self.follower.end(segment)

    def clear_self(self, at: float | None = None) -> None:
        """An interruption: everything not yet played is dropped, the mouth shuts; reports and audio
        of the segments known now are ignored from here on."""
        at = time.monotonic() if at is None else at
        with self._lock:
            if self.voice is not None and self.speaker is not None:
                cut = self.speaker.ring.read_pos + self.speaker.block
                self.voice.clear()
                blank_ring(self.speaker.ring, cut)
                self.self_line.blank(int(cut * ANALYSIS_RATE / self.speaker.rate))
                self.tracker.cleared(self.speaker.played(), self.speaker.rate, at)
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
            if self.voice is not None and self.speaker is not None:
                cut = self.speaker.ring.read_pos + self.speaker.block
                self.voice.hold(cut)
                blank_ring(self.speaker.ring, cut)
                self.self_line.blank(int(cut * ANALYSIS_RATE / self.speaker.rate))
            elif self.follower is not None:
                self.follower.pause(at)
        self.event(Event.PAUSED, at)

    def resume_self(self, at: float | None = None) -> None:
        at = time.monotonic() if at is None else at
        if self.voice is not None:
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
                self._fed.setdefault(int((where + self.delay) * FPS), time.monotonic())

    def event(self, kind: Event, at: float | None = None, **info: Any) -> None:
        """A conversation event at monotonic time ``at`` (None: now)."""
        at = time.monotonic() if at is None else at
        self._post(kind, self._line_time(kind, at), info)

    def self_backlog(self) -> float:
        """Player mode: seconds of voice fed and not yet played (what pacing a writer looks at)."""
        if self.voice is None or self.speaker is None:
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

    def _post(self, kind: Event, t: float, info: dict[str, Any]) -> None:
        event = ConversationEvent(kind, t, info)
        self.events.append((time.monotonic(), event))
        self.generator.on_event(event)

    # -- the session's own threads -------------------------------------------------------------------------
    def _segment_queued(self, segment: Segment, position: int) -> None:
        """Player mode, the feeder's thread: a segment's first sample went into the ring."""
        assert self.speaker is not None
        self.tracker.queued(segment, position)
        self._post(Event.SPEAKING_START, position / self.speaker.rate, {"segment": segment})

    def _queued(self, position: int, fed: float) -> None:
        assert self.speaker is not None
        self._fed.setdefault(int(position / self.speaker.rate * FPS), fed)

    def _pump_loop(self) -> None:
        while not self._halt.wait(PUMP_SECONDS):
            now = time.monotonic()
            if self.follower is not None:
                self.follower.pump(now)
            elif self.speaker is not None and self.voice is not None and self._started:
                for segment, end in self.tracker.poll(self.voice, self.speaker.played(), self.speaker.rate, now):
                    self._post(Event.SPEAKING_END, end / self.speaker.rate, {"segment": segment})

    def _frames(self, takes: Any) -> Any:
        jaw = BLENDSHAPE_INDEX["jawOpen"]
        for index, frame in enumerate(takes):
            self._jaw[index] = float(frame[0].face[jaw])
            self._jaw.pop(index - 300, None)
            yield frame

    def _dispatched(self, index: int) -> None:
        self.frames.append((index, time.monotonic(), self._jaw.get(index, 0.0)))

    def _sent(self, backend: str, frame: TargetFrame, done: float) -> None:
        fed = self._fed.pop(frame.index, None) if len(self._routes) == 1 else self._fed.get(frame.index)
        if fed is not None:
            self.fed_to_sent.setdefault(backend, Histogram()).add(1000.0 * (done - fed))
        captured = self.audio.frame_capture.get(frame.index)
        if captured is not None:
            self.capture_to_sent.setdefault(backend, Histogram()).add(1000.0 * (done - captured))

    # -- closing ---------------------------------------------------------------------------------------------
    def close(self) -> DriveResult:
        """End the run (backends ease out and close), write the report; returns the result."""
        if self._closed:
            assert self.result is not None
            return self.result
        self._closed = True
        self._halt.set()
        self.partner.close()
        self.audio.stop()
        if self._thread is not None:
            self._thread.join()
        if self._pump.ident is not None:
            self._pump.join(timeout=1.0)
        self._close_audio()
        if self.error is not None:
            raise self.error
        self.result = self._write_report()
        return self.result

    def _close_audio(self) -> None:
        if self.feeder is not None and self.feeder.ident is not None:
            self.feeder.stop()
            self.feeder.join(timeout=2.0)
        if self.speaker is not None:
            self.speaker.close()

    def figures(self) -> dict[str, Any]:
        return {
            "mode": self.request.mode,
            "self_lead_ms": round(1000.0 * self.self_lead, 1) if self.player else None,
            "delay_ms": None if self.player else round(1000.0 * self.delay, 1),
            "partner_delay_ms": round(1000.0 * self.partner_delay, 1),
            "self_fed_to_sent": {k: h.summary() for k, h in self.fed_to_sent.items()},
            "partner_capture_to_sent": {k: h.summary() for k, h in self.capture_to_sent.items()},
            "self_voice": self.feeder.report() if self.feeder is not None else self.follower.report(),  # type: ignore[union-attr]
            "speaker": self.speaker.report() if self.speaker is not None else None,
            "partner": {**self.partner.report(), **self.audio.report()},
            "events": [{"time": round(e.at, 3), "event": e.kind.value} for _, e in self.events],
            "dropped_self_seconds": round(self.voice.dropped, 3) if self.voice is not None else None,
        }

    def _write_report(self) -> DriveResult:
        figures = self.figures()
        context = {
            "generator": {"name": self.generator.name, "seed": self.request.seed},
            "live": figures,
            "outputs": [],
            "summary_lines": [f"live session ({self.request.mode}): {len(self.events)} conversation events"],
        }
        report = build_report(self._result, context, self._failed_at_open, self._hardware)
        report_path, summary_path = write_report(report, Path(self.request.out_dir))
        return DriveResult(report, report_path, summary_path, [])

    def __enter__(self) -> LiveSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
