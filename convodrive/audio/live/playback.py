"""The self voice's output stream, and where its samples are: the master clock of a live run.

The PortAudio callback copies the next block from the playback ring and notes, from PortAudio's
timing, when the block's first sample will leave the speaker (``outputBufferDacTime``, turned
into ``time.monotonic`` seconds). Each note says "sample n plays at monotonic time m", so
``position_at(m)`` is the number of seconds of the stream that have left the speaker by ``m``:
the run's clock reads it, and motion frame k goes out when sample k/30 s is being heard.

Notes are noisy by a fraction of a millisecond and wrong in two known cases, both handled: the
callbacks PortAudio makes to fill its buffers at the start come in one burst, often long before
the audio server really starts playing (PulseAudio waits a second or more), so notes count only
from the first callback that comes at least half a block after the one before (the stream is
then pulling at its own pace); and a stall (a server that stopped pulling for a while) moves the
time line, so a gap of several blocks between callbacks forgets the notes before it. The estimate
is the median of the last ``ANCHORS`` notes.

A stream that stops taking samples (an audio server that hung, a device unplugged) is given up
(``stopped``): its notes are frozen, so the clock goes on at the pace it had, and the
self voice feeder paces itself by that clock instead of the speaker; the run goes on unheard
rather than waiting for a speaker that will not come back.
"""

from __future__ import annotations

import collections
import statistics
import threading
import time
from typing import Any

import numpy as np

from convodrive.audio.live.devices import Device, close_stream, portaudio
from convodrive.audio.live.ring import SampleRing
from convodrive.audio.live.watch import Watch
from convodrive.plumbing.errors import UserError
from convodrive.plumbing.priority import CallbackPriority

BLOCK_SECONDS = 0.01
"""Callback period: 10 ms blocks."""
ANCHORS = 32
MAX_LEAD = 2.0
"""No output buffer plays more than this far ahead of its callback."""
STALL_BLOCKS = 5
"""A gap of this many block periods (or of most of the output latency, for servers that call back
in bursts) between callbacks means the time line moved: start over."""
STOPPED_SECONDS = 4.0
STOPPED_SHARE = 0.25
"""A paced stream that took less than this share of real time over the last ``STOPPED_SECONDS``
(or twice its output latency, if longer) has stopped; a hung audio server takes next to nothing.
A stream that underran resumes late: through PulseAudio's ALSA plugin into a null sink it takes
nothing for 1.85 s after any underrun, however short (measured by stopping a live run with
SIGSTOP for 0.3, 1 and 2 s), so the window is long enough to see it play again. Only time this process
watched counts: a process stopped or starved for longer than ``WATCH_GAP`` starts it over."""
WATCH_GAP = 0.5
START_SECONDS = 5.0
"""The same for a stream that has not yet settled into its pace (an audio server starting up)."""


class Playback:
    """Plays its ring on ``device`` (at ``rate`` if the device takes it, else at the device's own
    rate) and knows how much of it has left the speaker."""

    def __init__(self, device: Device, rate: int, ring_seconds: float, latency: float | str = "low") -> None:
        sd = portaudio()
        self.device = device
        self.rate = self._usable_rate(sd, device, rate)
        self.ring = SampleRing(int(ring_seconds * self.rate))
        """What the callback plays: the self voice queued ahead, sized by the generator's look-ahead."""
        self.block = max(1, int(round(self.rate * BLOCK_SECONDS)))
        self._mono = np.zeros(self.block * 4, np.float32)
        self._anchors: collections.deque[float] = collections.deque(maxlen=ANCHORS)
        self._paced = False
        self._last_call: float | None = None
        self.portaudio_underflows = 0
        self.stalls = 0
        self.callbacks = 0
        self._priority = CallbackPriority("speaker callback")
        self._closed = threading.Event()
        self._stopped: str | None = None
        self._started_at: float | None = None
        self._looks = Watch(max_gap=WATCH_GAP)
        self._window: collections.deque[tuple[float, int]] = collections.deque()
        """(monotonic time, ring samples taken) at each look over the window ``stopped`` judges."""
        self._frozen: float | None = None
        """The anchor the position keeps once the stream is given up."""
        self._latency = 0.0
        channels = 1
        try:
            sd.check_output_settings(device=device.index, channels=1, samplerate=self.rate)
        except Exception:
            channels = min(2, device.outputs)
        try:
            self._stream = sd.OutputStream(
                device=device.index,
                samplerate=self.rate,
                channels=channels,
                dtype="float32",
                blocksize=self.block,
                latency=latency,
                callback=self._callback,
            )
        except Exception as exc:
            raise UserError(f"--play {device.name!r}: cannot open it for playback ({exc})") from None
        self._latency = float(self._stream.latency)  # servers that buffer more call back in bursts

    @staticmethod
    def _usable_rate(sd: Any, device: Device, rate: int) -> int:
        """``rate`` if the device takes it, else the device's own rate (the caller resamples)."""
        try:
            sd.check_output_settings(device=device.index, samplerate=rate)
            return int(rate)
        except Exception:
            return int(device.default_rate)

    @property
    def latency(self) -> float:
        """PortAudio's output latency: how long a written block takes to reach the speaker."""
        return float(self._stream.latency)

    def start(self) -> None:
        self._stream.start()
        self._started_at = time.monotonic()

    def _callback(self, outdata: np.ndarray, frames: int, time_info: Any, status: Any) -> None:
        self._priority()
        if self._stopped is not None:  # given up: the clock runs on the frozen notes
            outdata.fill(0.0)
            return
        now = time.monotonic()
        first = self.ring.read_pos
        if len(self._mono) < frames:
            self._mono = np.zeros(frames, np.float32)
        mono = self._mono[:frames]
        self.ring.read_into(mono)
        outdata[:] = mono[:, None]
        self.callbacks += 1
        if status.output_underflow:
            self.portaudio_underflows += 1
        gap = None if self._last_call is None else now - self._last_call
        self._last_call = now
        if not self._paced:  # still the start-up burst: these timings are not yet real
            self._paced = gap is not None and gap >= 0.5 * BLOCK_SECONDS
            if not self._paced:
                return
        elif gap is not None and gap > max(STALL_BLOCKS * BLOCK_SECONDS, 0.75 * self._latency):
            self.stalls += 1
            self._anchors.clear()
        dac = time_info.outputBufferDacTime
        lead = (dac - time_info.currentTime) if dac > 0 else self.latency
        if 0.0 <= lead <= MAX_LEAD:  # anything else is a host API's nonsense, not a position
            self._anchors.append(now + lead - first / self.rate)

    def position_at(self, mono: float) -> float | None:
        """Seconds of the stream that have left the speaker at monotonic time ``mono``; None until
        the stream has told us where it is."""
        if self._frozen is not None:  # given up: a late callback cannot move the clock any more
            return mono - self._frozen
        anchors = list(self._anchors)
        if not anchors:
            return None
        return mono - statistics.median(anchors)

    def stopped(self) -> str | None:
        """Why the stream was given up, once it has stopped taking samples; None while it plays.

        Stopped means less than ``STOPPED_SHARE`` of real time taken over ``STOPPED_SECONDS``, so
        a callback now and then does not keep a dead stream alive. Before the stream
        is paced its server may still be starting, so it has ``START_SECONDS`` to get there. A
        stream given up before it ever said where it was starts its time line there, on the
        monotonic clock."""
        if self._stopped is not None or self._started_at is None:
            return self._stopped
        now = time.monotonic()
        if not self._paced:
            if now - self._started_at > START_SECONDS:
                self._give_up(f"it never started playing in {START_SECONDS:g} s", now)
            return self._stopped
        if self._looks.look(now):  # the first look, or after a gap: this process, not the stream, stopped
            self._window.clear()
        self._window.append((now, self.ring.read_pos))
        window = max(STOPPED_SECONDS, 2.0 * self._latency)
        while len(self._window) > 1 and now - self._window[1][0] >= window:
            self._window.popleft()  # the oldest look stays the last one at least a window back
        since, before = self._window[0]
        played = (self.ring.read_pos - before) / self.rate
        if now - since >= window and played < STOPPED_SHARE * (now - since):
            self._give_up(f"it took {played:.2f} s of audio in {now - since:.1f} s", now)
        return self._stopped

    def _give_up(self, why: str, now: float) -> None:
        anchors = list(self._anchors)
        self._frozen = statistics.median(anchors) if anchors else now - self.ring.read_pos / self.rate
        self._stopped = f"--play {self.device.name!r} stopped taking samples ({why})"

    def played(self) -> int:
        """Samples the callback has taken from the ring (ahead of the speaker by the latency)."""
        return self.ring.read_pos

    def drain(self, position: int, timeout: float) -> None:
        """Wait until sample ``position`` has left the speaker, or ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            now = time.monotonic()
            at = self.position_at(now)
            if at is not None and at * self.rate >= position:
                return
            time.sleep(0.005)

    def close(self) -> None:
        if self._closed.is_set():
            return
        self._closed.set()
        close_stream(self._stream, answering=self._stopped is None)

    def report(self) -> dict[str, Any]:
        anchors = list(self._anchors)
        spread = 1000.0 * statistics.median(abs(a - statistics.median(anchors)) for a in anchors) if anchors else None
        return {
            "device": self.device.name,
            "sample_rate": self.rate,
            "block_ms": round(1000.0 * self.block / self.rate, 2),
            "output_latency_ms": round(1000.0 * self.latency, 2),
            "underruns": self.ring.underruns,
            "underrun_ms": round(1000.0 * self.ring.underrun_samples / self.rate, 1),
            "portaudio_underflows": self.portaudio_underflows,
            "stalls": self.stalls,
            "callback_priority": self._priority.granted,
            "stopped": self._stopped,
            "timing_noise_ms": round(spread, 3) if spread is not None else None,
        }
