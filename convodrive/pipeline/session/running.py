"""A live session's run: its audio opened, the scheduler started, its clock, and its closing.

``SessionRun`` opens the voice, the partner, the speaker and the monitor (``sources``), then the
backends; runs the scheduler (in a thread of its own, ``start``, or the caller's, ``run``) with
the session's measurements (``measures``) hooked in; and on closing writes the report
(``report``). ``LiveSession`` adds what a voice agent calls.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Self

import numpy as np

from convodrive import FPS
from convodrive.audio.live.assembler import LiveAudio
from convodrive.audio.live.capture import NoPartner, PartnerInput, Recording
from convodrive.audio.live.feeder import SelfVoiceFeeder
from convodrive.audio.live.self_voice import FileVoice, NoVoice, VoiceSource
from convodrive.audio.live.timeline import Timeline
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.backends.base import Session
from convodrive.generators.base import ConversationEvent, Event, Generator
from convodrive.pipeline.backends import close_all, make_backends, open_backends, run_in_own_processes
from convodrive.pipeline.config import load_run_config
from convodrive.pipeline.run import DEFAULT_GENERATOR, DriveResult, make_generator
from convodrive.pipeline.session.follower import FollowedVoice
from convodrive.pipeline.session.inputs import PushedPartner, QueuedVoice, Segment
from convodrive.pipeline.session.measures import Measures
from convodrive.pipeline.session.playing import PlaybackTracker
from convodrive.pipeline.session.report import figures, write_session_report
from convodrive.pipeline.session.sources import (
    GENERATION_MARGIN,
    PARTNER_GRACE,
    RING_SPARE,
    SELF_JITTER,
    SELF_MARGIN,
    DrainingPlayback,
    Speaker,
    open_monitor,
    open_partner,
    open_speaker,
    open_voice_source,
)
from convodrive.plumbing.errors import UserError
from convodrive.scheduler import Clock, MonotonicClock, PlaybackClock, RunResult, Scheduler

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
    voice: str | None = None
    """Player mode: None (the framework feeds it), an audio file, ``-`` (raw PCM on stdin),
    ``tcp://HOST:PORT`` (a socket a speech synthesiser writes raw PCM into), or ``none``."""
    partner: str | None = None
    """None (the framework feeds it), a capture device (name, index, ``default``), an audio file
    played in real time as if captured, or ``none``."""
    speaker: str = "virtual"
    """Player mode: an output device (name, index, ``default``), or ``virtual`` (no sound card)."""
    monitor: str | None = None
    """A capture device hearing the speaker: the report then gives the audio–motion offset heard
    there, and ``sync.npz`` what it comes from."""
    self_rate: int = 24000
    """The speaker's rate for a fed voice; the rate of raw PCM on stdin or a socket."""
    play_latency: float | str = 0.1
    ahead: float = 0.1
    """Player mode, a fed voice: seconds queued in the speaker's ring beyond the look-ahead; the
    rest waits where a clear drops it at no cost."""
    delay: float | None = None
    """Follower mode: how late the motion follows the played voice (default: the generator's
    look-ahead plus the partner's grace and a generation margin)."""
    output_latency: float = 0.0
    """Seconds from a framework's "played" to the sound (network, jitter buffer, device)."""
    seconds: float | None = None
    """End the run after this many seconds of its clock."""
    labels: dict[str, str] = dataclasses.field(default_factory=dict)
    """How errors name the fields (``convodrive live``: its options, ``speaker`` as ``--play``)."""


class SessionRun:
    """See the module docstring."""

    def __init__(self, request: SessionRequest, generator: Generator | None = None) -> None:
        self.request = request
        self._check()
        self.config = load_run_config(request.config)
        self.generator_options: dict[str, Any] | None = None
        if generator is None:
            generator, options = make_generator(request.generator, self.config, request.generator_options, live=True)
            self.generator_options = options.as_dict()
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
        self._on_start: Callable[[], None] | None = None
        self.partner: PartnerInput = PushedPartner() if request.partner is None else NoPartner()
        self.self_line = Timeline()
        self.speaker: Speaker | None = None
        self.voice: VoiceSource | None = None
        self.feeder: SelfVoiceFeeder | None = None
        self.follower: FollowedVoice | None = None
        self.monitor: Recording | None = None
        self.audio: LiveAudio | None = None
        self.clock: Clock = MonotonicClock()
        self.tracker = PlaybackTracker()
        self.events: list[tuple[float, ConversationEvent]] = []
        """(monotonic time sent, event), in the order sent: what the generator was told."""
        self.measures = Measures()
        self.frames = self.measures.frames
        """(frame index, monotonic dispatch time, jawOpen) of the last ten minutes' frames."""
        self.fed_to_sent = self.measures.fed_to_sent
        self.capture_to_sent = self.measures.capture_to_sent
        self.routes: list[Any] = []
        self.failed_at_open: Any = None
        self.hardware: list[str] = []
        self._thread: threading.Thread | None = None
        self._pump: threading.Thread | None = None
        self._halt = threading.Event()
        self.run_result: RunResult | None = None
        self.result: DriveResult | None = None
        self.error: BaseException | None = None

    def label(self, field: str) -> str:
        return self.request.labels.get(field, field)

    def _check(self) -> None:
        request = self.request
        if request.mode not in ("player", "follower"):
            raise UserError(f"mode must be 'player' or 'follower', got {request.mode!r}")
        if not request.backends:
            raise UserError(f"name at least one backend with {self.label('backends')}")
        seconds = request.seconds
        if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
            raise UserError(f"{self.label('seconds')} must be positive and finite, got {seconds:g}")
        if request.mode == "follower" and request.voice is not None:
            raise UserError(f"follower mode: the framework plays the voice ({self.label('voice')} is for player mode)")
        if request.voice == "none" and request.partner == "none" and seconds is None:
            voice, partner = self.label("voice"), self.label("partner")
            raise UserError(
                f"{voice} none and {partner} none: nothing to listen to (give one, or {self.label('seconds')})"
            )

    # -- starting ------------------------------------------------------------------------------------
    def start(self, on_start: Callable[[], None] | None = None) -> None:
        """Open the audio and the backends (a ``UserError`` names what is wrong) and run in a
        thread of its own until ``close``. ``on_start`` is called once the clock runs."""
        self._open(on_start)
        self._thread = threading.Thread(target=self._run, name="live-run", daemon=True)
        self._thread.start()

    def run(self, on_start: Callable[[], None] | None = None) -> DriveResult:
        """Open as ``start`` does and run in this thread until the inputs end, ``seconds`` pass,
        or SIGINT/SIGTERM (in the main thread, as a drive); then close. ``convodrive live``."""
        self._open(on_start)
        self._run()
        return self.close()

    def _open(self, on_start: Callable[[], None] | None) -> None:
        request = self.request
        self._on_start = on_start
        planned = make_backends(request.backends, self.config, request.backend_options)
        run_in_own_processes(planned)  # a live run is paced: heavy and hardware backends must not shake it
        try:
            self._open_audio()
            out_dir = Path(request.out_dir)
            out_dir.mkdir(parents=True, exist_ok=True)
            voice_file = self.voice.path if isinstance(self.voice, FileVoice) else None
            session = Session(out_dir=out_dir, audio_path=voice_file, fps=FPS, offline=False, seed=request.seed)
            self.routes, self.failed_at_open = open_backends(planned, session)
        except BaseException:
            self._close_audio()
            raise
        self.hardware = [p.name for p in planned if p.backend.hardware]
        self.audio = audio = LiveAudio(
            self.self_line,
            self._self_end,
            self.partner,
            self.time_at,
            self.partner_delay,
            PARTNER_GRACE,
            stop_at=request.seconds,
            self_failed=self._self_failed,
            self_absent=isinstance(self.voice, NoVoice),
        )
        self.measures.frame_capture, self.measures.backends = audio.frame_capture, len(self.routes)
        try:
            self._start_audio()
            measures = self.measures
            self.scheduler = Scheduler(
                measures.frames_of(self.generator.stream_takes(measures.chunks(audio.chunks()), [request.seed])),
                self.routes,
                clock=self.clock,
                on_frame=measures.dispatched,
                on_start=self._clock_started,
                on_sent=measures.sent,
            )
        except BaseException:
            close_all(self.routes)
            self._close_audio()
            raise
        if self.follower is not None or isinstance(self.voice, QueuedVoice):
            self._pump = threading.Thread(target=self._pump_loop, name="live-session", daemon=True)
            self._pump.start()

    def _open_audio(self) -> None:
        """Every source, device and socket, in the order a user would fix them."""
        request = self.request
        if self.player and request.voice is not None:
            self.voice = open_voice_source(request.voice, request.self_rate, self.label("voice"))
        if request.partner is not None:
            ring = self.partner_delay + RING_SPARE
            self.partner = open_partner(request.partner, self.label("partner"), self._clock_running, ring)
        if self.player:
            self._open_player()
        else:
            self.self_line.fill_to(int(round(self.delay * ANALYSIS_RATE)))  # nothing played before time 0
            self.follower = FollowedVoice(
                self.self_line, self.time_at, self.delay, PARTNER_GRACE, request.output_latency
            )
            self.follower.on_start = lambda segment, at: self._post(Event.SPEAKING_START, at, {"segment": segment})
        if request.monitor is not None:
            self.monitor = open_monitor(request.monitor, self.label("monitor"))

    def _open_player(self) -> None:
        """The speaker (none for no voice) and the feeder that keeps the voice ahead of it."""
        request = self.request
        fed = self.voice is None
        rate, ring = self.voice.rate if self.voice is not None else request.self_rate, None
        if not isinstance(self.voice, NoVoice):
            ahead = self.self_lead + SELF_JITTER + (request.ahead if fed else 0.0)
            self.speaker = speaker = open_speaker(
                request.speaker, rate, ahead + RING_SPARE, request.play_latency, request.output_latency,
                self.label("speaker"),
            )  # fmt: skip
            rate, ring = speaker.rate, speaker.ring
            self.clock = PlaybackClock(DrainingPlayback(speaker, lambda: self.feeder))
            if fed:
                self.voice = QueuedVoice(rate, ring, ahead, self._segment_queued, self._queued)
        assert self.voice is not None
        self.feeder = SelfVoiceFeeder(
            self.voice,
            ring,
            rate,
            self.self_line,
            heard=self.speaker.played if self.speaker is not None else self._clock_samples(rate),
            lead=self.self_lead,
            jitter=SELF_JITTER,
            clock_now=self._clock_now,
            speaker_stopped=self.speaker.stopped if self.speaker is not None else None,
        )

    def _start_audio(self) -> None:
        if self.feeder is not None:
            self.feeder.start()
        self.partner.start()
        if self.monitor is not None:
            self.monitor.source.start()
            self.monitor.start()

    def _run(self) -> None:
        try:
            self.run_result = self.scheduler.run()  # closes every backend and the clock (the speaker)
        except BaseException as exc:  # handed to close(), which raises it
            self.error = exc

    def _clock_started(self) -> None:
        self._started = True
        if self._on_start is not None:
            self._on_start()

    # -- the clock -------------------------------------------------------------------------------------
    def time_at(self, mono: float) -> float | None:
        """The run's clock (seconds, the frames' time line) at monotonic time ``mono``; None
        before it runs."""
        if not self._started:
            return None
        if self.speaker is not None:
            return self.speaker.position_at(mono)
        return self.clock.now() - (time.monotonic() - mono)

    def _clock_running(self) -> bool:
        now = self.time_at(time.monotonic())
        return now is not None and now >= 0.0

    def _clock_now(self) -> float:
        return self.clock.now() if self._started else 0.0

    def _clock_samples(self, rate: int) -> Callable[[], int]:
        """How far a speaker would have got, in samples at ``rate``: the stand-in without one."""
        return lambda: int(max(self.clock.now(), 0.0) * rate) if self._started else 0

    def _self_end(self) -> int | None:
        """The time-line position where a finite voice ended; None while it goes on."""
        feeder = self.feeder
        if feeder is None or feeder.ended_at is None:
            return None
        return int(np.ceil(feeder.ended_at * ANALYSIS_RATE / feeder.rate))

    def _self_failed(self) -> Exception | None:
        """Why the voice stopped for good (a file that stopped decoding), as a ``UserError`` the
        run report gives; None while it goes on."""
        error = self.feeder.error if self.feeder is not None else None
        if error is None or isinstance(error, UserError) or not isinstance(error, Exception):
            return error if isinstance(error, Exception) else None
        return UserError(
            f"{self.label('voice')} {self.request.voice}: the self voice failed ({error.__class__.__name__}: {error})"
        )

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
        self.measures.fed_at(int(position / self.speaker.rate * FPS), fed)

    def _pump_loop(self) -> None:
        while not self._halt.wait(PUMP_SECONDS):
            now = time.monotonic()
            if self.follower is not None:
                self.follower.pump(now)
            elif self.speaker is not None and isinstance(self.voice, QueuedVoice) and self._started:
                self._poll_playback(self.speaker, self.voice, now)

    def _poll_playback(self, speaker: Speaker, voice: QueuedVoice, now: float) -> None:
        """Tell what started and finished playing by ``now``, at the times the speaker played it."""
        heard = speaker.position_at(now)
        if heard is None:
            return
        rate, zero = speaker.rate, now - heard  # when ring position 0 left the speaker
        for segment, end in self.tracker.poll(voice, int(heard * rate), rate, lambda pos: zero + pos / rate):
            self._post(Event.SPEAKING_END, end / rate, {"segment": segment})

    # -- closing ---------------------------------------------------------------------------------------------
    def close(self) -> DriveResult:
        """End the run (backends ease out and close), write the report; returns the result."""
        if self._closed:
            assert self.result is not None
            return self.result
        self._closed = True
        self._halt.set()
        self.partner.close()
        if self.audio is not None:
            self.audio.stop()
        if self._thread is not None:
            self._thread.join()
        if self._pump is not None:
            self._pump.join(timeout=1.0)
        self._close_audio()
        if self.error is not None:
            raise self.error
        self.result = write_session_report(self)
        return self.result

    def _close_audio(self) -> None:
        """Stop every thread and stream the session started (the clock has closed the speaker)."""
        if self.audio is not None:
            self.audio.stop()
        if self.feeder is not None and self.feeder.ident is not None:
            self.feeder.stop()
            self.feeder.join(timeout=2.0)  # it closes the voice source
        elif self.voice is not None:
            self.voice.close()
        self.partner.close()
        if self.monitor is not None:
            self.monitor.stop()
        if self.speaker is not None:
            self.speaker.close()

    def figures(self) -> dict[str, Any]:
        """The report's ``live`` section (``report.figures``)."""
        return figures(self)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
