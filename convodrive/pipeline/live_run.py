"""The audio side of a live run (``convodrive.pipeline.live`` drives it): the devices, sockets
and threads of both voices, the clock they make, and what is measured of them (latencies, the
audio–motion offset heard at the monitor).

Audio callbacks only copy samples (``audio.live``); the generator runs in the scheduler's
producer thread, each backend in its own worker, so none of them can hold up the audio.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.audio.live import capture
from convodrive.audio.live.assembler import LiveAudio
from convodrive.audio.live.capture import FileAsMicrophone, MicrophoneInput, NoPartner, PartnerInput, Recording
from convodrive.audio.live.devices import find_device
from convodrive.audio.live.feeder import SelfVoiceFeeder
from convodrive.audio.live.playback import Playback
from convodrive.audio.live.self_voice import NoVoice, TcpVoice, VoiceSource, open_voice
from convodrive.audio.live.timeline import Timeline
from convodrive.audio.source import ANALYSIS_RATE, SUPPORTED_EXTENSIONS, AudioChunk
from convodrive.eval.sync import LevelMeter, level_db, mouth_onsets, pair_onsets, speech_onsets
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.clip import MotionFrame
from convodrive.motion.targets import TargetFrame
from convodrive.pipeline.run import DEFAULT_GENERATOR
from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.errors import InputFileError, UserError
from convodrive.plumbing.stats import Histogram
from convodrive.scheduler import Clock, MonotonicClock, PlaybackClock

SELF_MARGIN = 0.015
"""Self voice queued this much beyond the look-ahead: the feeder's poll, resampling, generation."""
SELF_JITTER = 0.04
"""Room for a streamed voice to arrive unevenly before the feeder would pad it with silence."""
PARTNER_GRACE = capture.BLOCK_SECONDS + 0.005
"""A partner sample may arrive this long after capture (its block's length plus delivery)."""
GENERATION_MARGIN = 0.008
"""Time to make a frame once its audio is in: the assembler's poll (2 ms) and one generator step
(procedural's costs some two thousand small Python calls: 2-4 ms on a shared 2-core machine).
At 2 ms, a tenth of the frames of a live run there went out late."""
RING_SPARE = 1.0
"""Ring room beyond what the look-ahead needs, in seconds: what a CPU too busy to run us for a
while (a second) costs in neither underruns nor overruns."""


@dataclasses.dataclass
class LiveRequest:
    partner: str = "default"
    """A capture device (name, index, ``default``), an audio file played as if captured, or ``none``."""
    self_voice: str = "none"
    """An audio file, ``-`` (PCM on stdin), ``tcp://HOST:PORT``, or ``none``."""
    play: str = "default"
    monitor: str | None = None
    """A capture device hearing the speaker (a sink's monitor): measure the audio–motion offset."""
    self_rate: int = ANALYSIS_RATE
    """Sample rate of raw PCM on stdin or a socket."""
    seconds: float | None = None
    play_latency: float | str = 0.1
    generator: str = DEFAULT_GENERATOR
    backends: tuple[str, ...] = ("record",)
    config: str | Path | None = None
    out_dir: Path = Path("convodrive-out")
    seed: int = 0
    generator_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    backend_options: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)


class _DrainingPlayback:
    """What the clock holds in a live run: the playback, which on close first lets the end of a
    finished voice leave the speaker (at most ``DRAIN_SECONDS``)."""

    DRAIN_SECONDS = 1.0

    def __init__(self, playback: Playback, feeder: Callable[[], SelfVoiceFeeder | None]) -> None:
        self.playback = playback
        self._feeder = feeder

    def start(self) -> None:
        self.playback.start()

    def position_at(self, mono: float) -> float | None:
        return self.playback.position_at(mono)

    def close(self) -> None:
        feeder = self._feeder()
        if feeder is not None and feeder.ended_at is not None:
            self.playback.drain(feeder.ended_at, self.DRAIN_SECONDS)
        self.playback.close()


class LiveRun:
    """The audio side of one live run and its measurements; ``live`` drives it."""

    def __init__(self, request: LiveRequest, need: float) -> None:
        self.request = request
        self.self_lead = need + SELF_MARGIN
        self.partner_delay = need + PARTNER_GRACE + GENERATION_MARGIN
        self.voice: VoiceSource | None = None
        self.partner: PartnerInput | None = None
        self.playback: Playback | None = None
        self.monitor: Recording | None = None
        self.feeder: SelfVoiceFeeder | None = None
        self.audio: LiveAudio | None = None
        self.clock: Clock = MonotonicClock()
        self.self_line = Timeline()
        self._started = False
        self._self_level = LevelMeter(ANALYSIS_RATE)
        self._jaw: list[float] = []
        self._generated: dict[int, float] = {}
        self._dispatch: list[float] = []
        self.capture_to_generated = Histogram()
        self.generated_to_dispatched = Histogram()
        self.capture_to_sent: dict[str, Histogram] = {}

    # -- opening ----------------------------------------------------------------------------------
    def open_audio(self) -> None:
        """Open every device and socket before any backend, so a mistake costs nothing."""
        request = self.request
        self.voice = open_voice(request.self_voice, request.self_rate)
        if isinstance(self.voice, TcpVoice) and self.voice.token is not None:
            sys.stderr.write(
                f"convodrive: --self {self.voice.describe}: a speaker must first send the line "
                f"{self.voice.token}, then its PCM\n"
            )
            sys.stderr.flush()
        self.partner = self._open_partner(request.partner)
        rate = self.voice.rate
        ring = None
        if not isinstance(self.voice, NoVoice):
            device = find_device(request.play, "output", "--play")
            ring_seconds = self.self_lead + SELF_JITTER + RING_SPARE
            self.playback = Playback(device, rate, ring_seconds, request.play_latency)
            rate, ring = self.playback.rate, self.playback.ring
            self.clock = PlaybackClock(_DrainingPlayback(self.playback, lambda: self.feeder))
        if request.monitor is not None:
            device = find_device(request.monitor, "input", "--monitor")
            self.monitor = Recording(MicrophoneInput(device, ring_seconds=2.0, keep_timing=True))
        self.feeder = SelfVoiceFeeder(
            self.voice,
            ring,
            rate,
            self.self_line,
            heard=self._heard_by(rate),
            lead=self.self_lead,
            jitter=SELF_JITTER,
            clock_now=self._clock_now,
            speaker_stopped=self.playback.stopped if self.playback is not None else None,
        )
        self.audio = LiveAudio(
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

    def _open_partner(self, spec: str) -> PartnerInput:
        if spec == "none":
            return NoPartner()
        path = Path(spec)
        if path.is_file() or path.suffix.lower() in SUPPORTED_EXTENSIONS or "/" in spec:
            if not path.exists():
                raise InputFileError(path, "no such file (--partner takes an audio file or a capture device)")
            return FileAsMicrophone(path, ready=self._clock_running)
        device = find_device(spec, "input", "--partner")
        return MicrophoneInput(
            device, ring_seconds=self.partner_delay + RING_SPARE, latency=capture.PARTNER_LATENCY_SECONDS
        )

    def _heard_by(self, rate: int) -> Callable[[], int]:
        """How far the speaker has got, in ring samples (the clock's stand-in without a speaker)."""
        if self.playback is not None:
            playback = self.playback
            return playback.played
        return lambda: int(max(self.clock.now(), 0.0) * rate) if self._started else 0

    # -- running ----------------------------------------------------------------------------------
    def start(self) -> None:
        assert self.feeder is not None and self.partner is not None
        self.feeder.start()
        self.partner.start()
        if self.monitor is not None:
            self.monitor.source.start()
            self.monitor.start()

    def clock_started(self, on_start: Callable[[], None] | None) -> None:
        self._started = True
        if on_start is not None:
            on_start()

    def _clock_running(self) -> bool:
        now = self.time_at(time.monotonic())
        return now is not None and now >= 0.0

    def _clock_now(self) -> float:
        return self.clock.now() if self._started else 0.0

    def time_at(self, mono: float) -> float | None:
        """The run's clock at monotonic time ``mono``; None before it runs."""
        if not self._started:
            return None
        if self.playback is not None:
            return self.playback.position_at(mono)
        return self.clock.now() - (time.monotonic() - mono)

    def _self_failed(self) -> Exception | None:
        """Why the self voice stopped for good (a file that stopped decoding), as a ``UserError``
        the run report gives; None while it goes on."""
        error = self.feeder.error if self.feeder is not None else None
        if error is None or isinstance(error, UserError) or not isinstance(error, Exception):
            return error if isinstance(error, Exception) else None
        return UserError(
            f"--self {self.request.self_voice}: the self voice failed ({error.__class__.__name__}: {error})"
        )

    def _self_end(self) -> int | None:
        feeder = self.feeder
        if feeder is None or feeder.ended_at is None:
            return None
        return int(np.ceil(feeder.ended_at * ANALYSIS_RATE / feeder.rate))

    def chunks(self) -> Iterator[AudioChunk]:
        assert self.audio is not None
        for chunk in self.audio.chunks():
            self._self_level.push(chunk.self_voice)
            yield chunk

    def frames(self, takes: Iterator[tuple[MotionFrame, ...]]) -> Iterator[tuple[MotionFrame, ...]]:
        """The generator's frames, noting when each was made and how open its mouth is."""
        jaw = BLENDSHAPE_INDEX["jawOpen"]
        for index, frame in enumerate(takes):
            now = time.monotonic()
            self._generated[index] = now
            self._generated.pop(index - 300, None)
            self._jaw.append(float(frame[0].face[jaw]))
            assert self.audio is not None
            captured = self.audio.frame_capture.get(index)
            if captured is not None:
                self.capture_to_generated.add(1000.0 * (now - captured))
            yield frame

    def dispatched(self, index: int) -> None:
        now = time.monotonic()
        self._dispatch.append(now)
        made = self._generated.get(index)
        if made is not None:
            self.generated_to_dispatched.add(1000.0 * (now - made))

    def sent(self, backend: str, frame: TargetFrame, done: float) -> None:
        assert self.audio is not None
        captured = self.audio.frame_capture.get(frame.index)
        if captured is not None:
            self.capture_to_sent.setdefault(backend, Histogram()).add(1000.0 * (done - captured))

    def close(self) -> None:
        """Stop every thread and stream this run started (the clock closes the speaker)."""
        if self.audio is not None:
            self.audio.stop()
        if self.feeder is not None and self.feeder.ident is not None:
            self.feeder.stop()
            self.feeder.join(timeout=2.0)  # it closes the voice source
        elif self.voice is not None:
            self.voice.close()
        if self.partner is not None:
            self.partner.close()
        if self.monitor is not None:
            self.monitor.stop()
        if self.playback is not None:
            self.playback.close()

    # -- measuring --------------------------------------------------------------------------------
    def _offsets(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """The audio–motion offset heard at the monitor, and the generator's own offset."""
        jaw = np.asarray(self._jaw)
        dispatch = np.asarray(self._dispatch)
        n = min(len(jaw), len(dispatch))
        own = pair_onsets(speech_onsets(self._self_level.db), mouth_onsets(jaw) / FPS).summary()
        if self.monitor is None:
            return {"measured": False, "why": "give --monitor DEVICE (a capture of the speaker) to measure it"}, own
        recording = self.monitor.samples()
        db = level_db(recording, ANALYSIS_RATE)
        audio_mono = self.monitor.mono_at((speech_onsets(db) * ANALYSIS_RATE).astype(np.int64))
        motion_mono = dispatch[mouth_onsets(jaw[:n])] if n else np.zeros(0)
        heard = pair_onsets(audio_mono, motion_mono).summary()
        heard["measured"] = True
        heard["monitor_seconds"] = round(len(recording) / ANALYSIS_RATE, 3)
        return heard, own

    def write_evidence(self, out_dir: Path) -> list[Path]:
        """``sync.npz``: per-frame dispatch times and mouth opening, the monitor recording and its
        capture times, the self voice's levels: everything the offset figures come from."""
        if self.monitor is None:
            return []
        recording = self.monitor.samples()
        index = np.arange(0, len(recording), ANALYSIS_RATE // 10)
        path = out_dir / "sync.npz"
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(
                    fh,
                    frame_dispatch_mono=np.asarray(self._dispatch),
                    jaw_open=np.asarray(self._jaw, np.float32),
                    monitor=np.clip(recording * 32767.0, -32768, 32767).astype(np.int16),
                    monitor_rate=np.int64(ANALYSIS_RATE),
                    monitor_index=index,
                    monitor_mono=self.monitor.mono_at(index),
                    self_level_db=self._self_level.db.astype(np.float32),
                )
        return [path]

    def report(self) -> dict[str, Any]:
        assert self.feeder is not None and self.partner is not None and self.audio is not None
        heard, own = self._offsets()
        events = sorted(self.feeder.events + self.audio.events, key=lambda e: (e["time"] is None, e["time"] or 0.0))
        sync_error = None
        if heard.get("median_ms") is not None and own.get("median_ms") is not None:
            sync_error = round(heard["median_ms"] - own["median_ms"], 1)
        return {
            "clock": "playback" if self.playback is not None else "monotonic",
            "self_voice": self.feeder.report(),
            "playback": self.playback.report() if self.playback is not None else None,
            "partner": {**self.partner.report(), **self.audio.report()},
            "latency_ms": {
                "self_lead": round(1000.0 * self.self_lead, 1),
                "partner_delay": round(1000.0 * self.audio.partner_delay, 1),
                "partner_capture_to_generated": self.capture_to_generated.summary(),
                "generated_to_dispatched": self.generated_to_dispatched.summary(),
                "partner_capture_to_sent": {k: h.summary() for k, h in self.capture_to_sent.items()},
            },
            "audio_motion_offset": heard,
            "generator_offset": own,
            "sync_error_ms": sync_error,
            "events": events,
        }
