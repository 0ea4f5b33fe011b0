"""The partner's voice in a live run: a microphone, or a file played in real time as if it were one.

Both hand over captured blocks with the monotonic time their first sample was captured. A
microphone's time comes from PortAudio's ``inputBufferAdcTime``: each callback notes "sample n was
captured at monotonic time m", and, as for playback (``playback``), the median over the last
callbacks gives a steady mapping that ignores the start-up bursts of an audio server. A
microphone that goes away (its stream ends, or no callback for ``LOST_SECONDS``) is reported and
then heard as silence; the run goes on. One that only went quiet (an audio server that paused) is
taken back as soon as its callbacks come again. A process starved of CPU (or stopped) hears no
callbacks either, but that silence is its own, not the microphone's: only silence that the run
watched while it was itself running counts.
"""

from __future__ import annotations

import abc
import collections
import statistics
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.audio.live.devices import Device, close_stream, portaudio
from convodrive.audio.live.ring import SampleRing
from convodrive.audio.live.watch import Watch
from convodrive.audio.resample import StreamResampler
from convodrive.audio.source import ANALYSIS_RATE, AudioSource, ChannelMap
from convodrive.plumbing.errors import UserError
from convodrive.plumbing.priority import CallbackPriority

BLOCK_SECONDS = 0.005
"""Capture block: 5 ms (a sample waits at most this long for its block to be handed over)."""
PARTNER_LATENCY_SECONDS = 0.01
"""Capture latency asked of PortAudio for the partner. Through PulseAudio's ALSA plugin, 20 ms
comes as bursts of four blocks every 20 ms (arrival age p90 16 ms under load), 10 ms as one block
every 5 ms (p90 7 ms); ``bench.bench_capture`` measures it. A recording (``--monitor``), timed
afterwards, keeps the roomier 20 ms."""
LOST_SECONDS = 2.0
"""A microphone silent (no callbacks at all) for this long has gone away. A pulled USB
microphone, or a PulseAudio server that went away, ends its stream at once (``finished``), so
this verdict is for a device that hangs; a busy audio server can hold a stream's callbacks for
over half a second (a loaded CI machine did, and the run gave up a working microphone). The run
never waits on a silent microphone meanwhile (overdue audio is filled with silence), so a later
verdict costs only its report line coming later."""
WATCH_GAP = 0.25
"""Two looks at ``lost`` further apart than this: the run itself was away (starved or stopped)."""
START_SECONDS = 5.0
"""An audio server may take a second or so to start a stream; past this, it never will."""
ANCHORS = 32

Captured = tuple[np.ndarray, float]
"""Samples at the analysis rate, and the monotonic time their first sample was captured."""


class PartnerInput(abc.ABC):
    describe: str = ""
    finite: bool = False
    absent: bool = False
    """True for ``--partner none``: nobody to listen to, so nothing whose end ends the run."""

    @abc.abstractmethod
    def start(self) -> None: ...

    @abc.abstractmethod
    def pull(self) -> list[Captured]:
        """Blocks captured since the last pull, oldest first."""

    def ended(self) -> bool:
        """True once a finite input has delivered everything."""
        return False

    def lost(self) -> str | None:
        """Why the input went away, once it has; None while it works."""
        return None

    def failed(self) -> Exception | None:
        """Why a finite input stopped for good before its end (a file that stopped decoding),
        once everything before that has been pulled; the run ends there."""
        return None

    def close(self) -> None:  # noqa: B027 (optional hook)
        """Stop listening; a second call does nothing."""

    def report(self) -> dict[str, Any]:
        return {"source": self.describe}


class NoPartner(PartnerInput):
    """``--partner none``: nobody to listen to."""

    finite = True
    absent = True
    describe = "none"

    def start(self) -> None:
        pass

    def pull(self) -> list[Captured]:
        return []

    def ended(self) -> bool:
        return True


class MicrophoneInput(PartnerInput):
    """A capture device through PortAudio; the callback only copies into a ring."""

    def __init__(
        self, device: Device, ring_seconds: float, latency: float | str = 0.02, keep_timing: bool = False
    ) -> None:
        sd = portaudio()
        self.device = device
        self.timing: list[tuple[int, float]] | None = [] if keep_timing else None
        """Every callback's (ring position, monotonic time of ring position 0), when kept."""
        self.describe = f"device {device.index} {device.name!r}"
        try:
            sd.check_input_settings(device=device.index, channels=1, samplerate=ANALYSIS_RATE)
            self.rate = ANALYSIS_RATE
        except Exception:
            self.rate = int(device.default_rate)
        self._resampler = StreamResampler(self.rate, ANALYSIS_RATE) if self.rate != ANALYSIS_RATE else None
        self.ring = SampleRing(int(ring_seconds * self.rate))
        self.block = int(round(BLOCK_SECONDS * self.rate))
        self._anchors: collections.deque[float] = collections.deque(maxlen=ANCHORS)
        self._last_call: float | None = None
        self._started_at: float | None = None
        self._finished = threading.Event()
        self._lost: str | None = None
        self._quiet_since: float | None = None
        """When the microphone was found silent (lost, but it may come back)."""
        self._watch = Watch(max_gap=WATCH_GAP)
        """Since when ``lost`` has been asked often enough to have seen callbacks, had there been any."""
        self.portaudio_overflows = 0
        self.callbacks = 0
        self._priority = CallbackPriority("capture callback")
        self.longest_gap = 0.0
        """The longest time between two callbacks (a stall of the audio server, or of this process)."""
        self._closed = False
        try:
            self._stream = sd.InputStream(
                device=device.index,
                samplerate=self.rate,
                channels=1,
                dtype="float32",
                blocksize=self.block,
                latency=latency,
                callback=self._callback,
                finished_callback=self._finished.set,
            )
        except Exception as exc:
            raise UserError(f"--partner {device.name!r}: cannot open it for capture ({exc})") from None

    def start(self) -> None:
        self._stream.start()
        self._started_at = time.monotonic()

    def _callback(self, indata: np.ndarray, frames: int, time_info: Any, status: Any) -> None:
        self._priority()
        now = time.monotonic()
        first = self.ring.write_pos
        self.ring.write_or_drop(indata[:, 0])
        self.callbacks += 1
        if status.input_overflow:
            self.portaudio_overflows += 1
        if self._last_call is not None:
            gap = now - self._last_call
            self.longest_gap = max(self.longest_gap, gap)
            if gap > 5 * BLOCK_SECONDS:
                self._anchors.clear()  # a stall moved the time line: start over
        self._last_call = now
        adc = time_info.inputBufferAdcTime
        age = (time_info.currentTime - adc) if adc > 0 else frames / self.rate
        anchor = now - age - first / self.rate
        self._anchors.append(anchor)
        if self.timing is not None:
            self.timing.append((first, anchor))

    def pull(self) -> list[Captured]:
        first = self.ring.read_pos
        data = self.ring.read(self.ring.available())
        anchors = list(self._anchors)
        if not len(data) or not anchors:
            return []
        captured = statistics.median(anchors) + first / self.rate
        if self._resampler is not None:
            captured -= self._resampler.latency_samples / self.rate  # held back: older samples come out
            data = self._resampler.push(data)
        return [(data, captured)]

    def lost(self) -> str | None:
        if self._quiet_since is not None and self._last_call is not None and self._last_call > self._quiet_since:
            self._lost = self._quiet_since = None  # its callbacks came back
        if self._lost is None and self._started_at is not None:
            now = time.monotonic()
            self._watch.look(now)  # after a gap (this process starved or stopped) the silence starts over
            quiet = now - max(self._last_call or self._started_at, self._watch.since or now)
            if self._finished.is_set():
                self._lost = f"{self.describe} stopped delivering audio (its stream ended)"
            elif self._last_call is not None and quiet > LOST_SECONDS:
                self._lost = f"{self.describe} stopped delivering audio (nothing for {LOST_SECONDS:g} s)"
                self._quiet_since = now
            elif self._last_call is None and now - self._started_at > START_SECONDS:
                self._lost = f"{self.describe} delivered no audio in its first {START_SECONDS:g} s"
        return self._lost

    def close(self) -> None:
        if self._closed:
            return
        answering = self.lost() is None
        self._closed = True
        close_stream(self._stream, answering=answering)

    def report(self) -> dict[str, Any]:
        return {
            "source": self.describe,
            "sample_rate": self.rate,
            "input_latency_ms": round(1000.0 * float(self._stream.latency), 2),
            "overruns": self.ring.overruns,
            "overrun_ms": round(1000.0 * self.ring.overrun_samples / self.rate, 1),
            "portaudio_overflows": self.portaudio_overflows,
            "longest_callback_gap_ms": round(1000.0 * self.longest_gap, 1),
            "callback_priority": self._priority.granted,
        }


class FileAsMicrophone(PartnerInput):
    """A recording delivered in 10 ms blocks at the pace of ``time.monotonic``, as a microphone
    would deliver it; it begins when ``ready()`` says the run's clock is running."""

    finite = True

    def __init__(self, path: Path, ready: Callable[[], bool]) -> None:
        self.source = AudioSource(path, ChannelMap(0, None))
        self.describe = f"file {path}"
        self._ready = ready
        self._blocks: collections.deque[Captured] = collections.deque()
        self._done = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._deliver, name="partner-file", daemon=True)
        self.delivered = 0
        self.error: Exception | None = None

    def start(self) -> None:
        self._thread.start()

    def _deliver(self) -> None:
        try:
            self._deliver_blocks()
        except Exception as exc:  # a file that stops decoding part-way: the run ends there
            self.error = exc
        finally:
            self._done.set()

    def _deliver_blocks(self) -> None:
        block = int(BLOCK_SECONDS * ANALYSIS_RATE)
        while not self._ready() and not self._stop.is_set():
            time.sleep(0.002)
        t0 = time.monotonic()
        for chunk in self.source.chunks(block):
            due = t0 + (chunk.start + len(chunk)) / ANALYSIS_RATE
            while not self._stop.is_set() and time.monotonic() < due:
                time.sleep(min(0.002, max(due - time.monotonic(), 0)))
            if self._stop.is_set():
                break
            self._blocks.append((chunk.self_voice.astype(np.float32), t0 + chunk.start / ANALYSIS_RATE))
            self.delivered += len(chunk)

    def pull(self) -> list[Captured]:
        out = []
        while self._blocks:
            out.append(self._blocks.popleft())
        return out

    def ended(self) -> bool:
        return self._done.is_set() and not self._blocks

    def failed(self) -> Exception | None:
        return self.error if self.ended() else None

    def close(self) -> None:
        self._stop.set()

    def report(self) -> dict[str, Any]:
        return {"source": self.describe, "delivered_seconds": round(self.delivered / ANALYSIS_RATE, 3)}


class Recording(threading.Thread):
    """Keeps everything a capture device delivers for the whole run (``--monitor``), to measure
    afterwards when the speaker played what.

    Capture times are worked out afterwards, from every callback's timing: a server may revise
    its reported latency once a stream settles (by tens of milliseconds when a sink starts
    playing), so each sample's time is the median of the timings from ``BEFORE`` seconds before it
    to ``AFTER`` seconds after it, leaving out the first ``SETTLE`` seconds of the stream. A server
    that stalls (starved of CPU, a sink that stops) moves the time line by the stall: the timings
    jump by more than ``JUMP`` seconds there, and each sample takes the median of its own side
    only (a monitor stalled 1.7 s once had every sample before the stall timed after it).
    """

    BEFORE, AFTER, SETTLE, JUMP = 2.0, 8.0, 1.0, 0.1

    def __init__(self, source: MicrophoneInput) -> None:
        super().__init__(name="monitor", daemon=True)
        if source.timing is None:
            source.timing = []
        self.source = source
        self._blocks: list[np.ndarray] = []
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.wait(0.02):
            self._pull()

    def _pull(self) -> None:
        data = self.source.ring.read(self.source.ring.available())
        if len(data):
            self._blocks.append(data)

    def stop(self) -> None:
        self._halt.set()
        if self.is_alive():
            self.join()
        self._pull()
        self.source.close()

    def samples(self) -> np.ndarray:
        """Everything captured, at the analysis rate."""
        data = np.concatenate(self._blocks) if self._blocks else np.zeros(0, np.float32)
        if self.source.rate != ANALYSIS_RATE:
            resampler = StreamResampler(self.source.rate, ANALYSIS_RATE)
            data = np.concatenate([resampler.push(data), resampler.finish()])
        return data

    def mono_at(self, index: np.ndarray) -> np.ndarray:
        """Monotonic capture times of sample indices (at the analysis rate) of ``samples``."""
        timing = np.asarray(self.source.timing or [], float).reshape(-1, 2)
        index = np.asarray(index, float) * self.source.rate / ANALYSIS_RATE
        if not len(timing):
            return np.full(index.shape, np.nan)
        rate = self.source.rate
        settled = timing[timing[:, 0] >= timing[0, 0] + self.SETTLE * rate]
        if len(settled):
            timing = settled
        flat = index.reshape(-1)
        lo = np.searchsorted(timing[:, 0], flat - self.BEFORE * rate)
        hi = np.searchsorted(timing[:, 0], flat + self.AFTER * rate, side="right")
        nearest = np.clip(np.searchsorted(timing[:, 0], flat), 0, len(timing) - 1)
        starts = np.concatenate([[0], np.flatnonzero(np.abs(np.diff(timing[:, 1])) > self.JUMP) + 1, [len(timing)]])
        side = np.clip(np.searchsorted(timing[starts[1:-1], 0], flat, side="right"), 0, len(starts) - 2)
        lo, hi = np.maximum(lo, starts[side]), np.minimum(hi, starts[side + 1])
        nearest = np.clip(nearest, starts[side], starts[side + 1] - 1)
        anchors = [np.median(timing[a:b, 1]) if b > a else timing[n, 1] for a, b, n in zip(lo, hi, nearest)]
        return (np.asarray(anchors) + flat / rate).reshape(index.shape)
