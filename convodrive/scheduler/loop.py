"""The scheduler's loop (DESIGN, "Scheduler"): one clock, a producer, one worker per backend.

- The generator runs in a producer thread that also retargets and fills a bounded buffer with
  finished target frames, so generation runs ahead of the clock but never without bound, and the
  clock thread does nothing but wait for deadlines and hand frames out.
- Frame k is due at ``k / fps`` on the run's clock (``convodrive.scheduler.clock``). A frame that
  reaches the clock after its deadline goes out at once and the next deadlines stay where they
  were, so lateness never accumulates into drift.
- Each backend has its own worker. On a paced clock a real-time backend (hardware, a live window)
  is fed through a latest-value slot, so a slow or failing backend drops its own frames and never
  stalls the clock or the others; a file backend gets a non-blocking backlog, so it receives every
  frame, late if it must. On a simulated clock every backend gets a small blocking queue.
- SIGINT and SIGTERM stop the clock; every backend is still closed, from its own worker, so its
  outputs end complete (file backends first take the frames already made). A second signal, or
  one that comes after the clock has ended, stops at once: waiting frames are dropped and each
  backend is told to ``hurry`` (servos cut torque instead of easing).
- Heavy backends may run in processes of their own (``convodrive.scheduler.process``); the loop
  does not know: to it they are backends like the others.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import signal
import threading
import time
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.motion.clip import MotionFrame
from convodrive.motion.targets import TargetFrame
from convodrive.plumbing.errors import UserError, error_line
from convodrive.plumbing.priority import clock_thread_priority, realtime_priority
from convodrive.scheduler.clock import Clock
from convodrive.scheduler.producer import FrameSource, Producer
from convodrive.scheduler.report import RunResult
from convodrive.scheduler.route import Route
from convodrive.scheduler.slots import END
from convodrive.scheduler.workers import BackendWorker, OnSent

_NO_VALUES = np.zeros(0)
_NO_VALUES.setflags(write=False)

log = logging.getLogger(__name__)

DrainCallback = Callable[[int, int, list[str]], None]
"""Called about 4 times a second after the clock ends, while backends finish: (frames done, frames
to do, names of the backends still at work)."""


class Scheduler:
    """Drives ``routes`` from ``source`` at ``fps`` on ``clock``; ``run`` returns a ``RunResult``."""

    def __init__(
        self,
        source: FrameSource,
        routes: Sequence[Route],
        *,
        clock: Clock,
        fps: float = FPS,
        expected_frames: int | None = None,
        audio_seconds: float | None = None,
        buffer_frames: int = 30,
        on_frame: Callable[[int], None] | None = None,
        on_start: Callable[[], None] | None = None,
        on_sent: OnSent | None = None,
        on_drain: DrainCallback | None = None,
        start_delay: float = 0.05,
    ) -> None:
        self.routes = list(routes)
        self.clock = clock
        self.fps = float(fps)
        self.expected_frames = expected_frames
        self.audio_seconds = audio_seconds
        self.on_frame = on_frame
        self.on_start = on_start
        self.on_sent = on_sent
        self.on_drain = on_drain
        self.start_delay = start_delay
        self._producer = Producer(source, self._target_frames, buffer_frames, paced=clock.paced)
        self._stop = threading.Event()
        self._interrupted = False
        self._hurried = False
        self.stop_signal: str | None = None
        """The signal that stopped the run (``"SIGINT"``, ``"SIGTERM"``), if one did."""
        self._workers: list[BackendWorker] = []
        self._clock_done = False
        self._started = False
        self.clock_priority = "normal"
        self._clock_seconds = 0.0

    def request_stop(self) -> None:
        """Stop at the next frame boundary (what SIGINT and SIGTERM do)."""
        self._interrupted = True
        self._stop.set()

    def hurry(self) -> None:
        """Stop at once: drop the frames backends have not taken yet, and cut their closing short."""
        self._hurried = True
        self.request_stop()
        for w in self._workers:
            w.hurry()

    def run(self) -> RunResult:
        previous = self._install_signal_handlers()
        paced = self.clock.paced
        workers = self._workers = [BackendWorker(r, paced, self._elapsed, self.on_sent) for r in self.routes]
        wall_start = time.monotonic()
        jitter: list[float] = []
        late = 0
        frames = 0
        drift = 0.0
        input_error: str | None = None
        try:
            with realtime_priority(paced) as self.clock_priority:
                for w in workers:
                    w.start()
                self._producer.start()
                with clock_thread_priority(paced) as policy:
                    if policy:
                        self.clock_priority = f"{policy}, {self.clock_priority}"
                    frames, jitter, late, drift = self._clock_loop(workers)
                self._clock_done = True
            error = self._producer.error
            if isinstance(error, UserError):  # the input ended the run (audio that stopped decoding)
                input_error = str(error)
            elif error is not None and not isinstance(error, KeyboardInterrupt):
                raise error
        finally:
            self._producer.stop_event.set()
            self._clock_done = True
            for w in workers:
                w.slot.close()
            self._join(workers)
            self.clock.close()
            self._restore_signal_handlers(previous)
        wall = time.monotonic() - wall_start
        return RunResult(
            mode="realtime" if paced else "offline",
            frames=frames,
            expected_frames=self.expected_frames,
            wall_seconds=wall,
            clock_seconds=self._clock_seconds,
            jitter_ms=jitter,
            late_frames=late,
            generator_seconds=self._producer.generator_seconds,
            audio_seconds=self.audio_seconds if self.audio_seconds is not None else frames / self.fps,
            drift_frames=drift,
            interrupted=self._interrupted,
            stop_signal=self.stop_signal,
            retarget_seconds=self._producer.prepare_seconds,
            backends=[w.stats for w in workers],
            backend_reports={w.stats.name: _safe_call(w.route.backend.report) for w in workers},
            backend_health={w.stats.name: _safe_call(w.route.backend.health) for w in workers},
            clock_priority=self.clock_priority,
            input_error=input_error,
        )

    def _join(self, workers: list[BackendWorker]) -> None:
        """Wait for every worker to finish its backlog and close its backend, reporting progress."""
        for w in workers:
            if w.ident is None:  # never started (interrupted at once): its backend still must close
                w.close_backend()
        busy = [w for w in workers if w.ident is not None]
        total = sum(w.slot.pending() for w in busy) + len(busy)  # + the frame or close in hand
        while busy:
            busy[0].join(timeout=0.25)
            busy = [w for w in busy if w.is_alive()]
            if self.on_drain is not None and busy:
                left = sum(w.slot.pending() for w in busy) + len(busy)
                self.on_drain(max(total - left, 0), total, [w.stats.name for w in busy])

    def _elapsed(self) -> float:
        return self.clock.now() if self._started else 0.0

    def _clock_loop(self, workers: list[BackendWorker]) -> tuple[int, list[float], int, float]:
        """Dispatch frames until the source ends or a stop is requested."""
        clock = self.clock
        jitter: list[float] = []
        late = 0
        index = 0
        period = 1.0 / self.fps
        last_dispatch = 0.0
        wall_t0 = 0.0
        while True:
            item = self._next_frame()
            if item is END:
                break
            if index == 0:  # the clock starts once the first frame exists
                clock.start(self.start_delay)
                wall_t0 = time.monotonic() + self.start_delay
                self._started = True
                if self.on_start is not None:
                    self.on_start()
            deadline = index * period
            if clock.paced:
                if clock.now() > deadline:
                    late += 1
                else:
                    clock.wait_until(deadline)
                last_dispatch = clock.now()
                jitter.append((last_dispatch - deadline) * 1000.0)
            self._dispatch(item, workers, time.monotonic() if clock.paced else 0.0)
            if self.on_frame is not None:
                self.on_frame(index)
            index += 1
        drift = 0.0
        if index:
            if clock.paced:
                self._clock_seconds = max(last_dispatch, 0.0) + period
                drift = last_dispatch * self.fps - (index - 1)
            else:
                self._clock_seconds = max(time.monotonic() - wall_t0, 0.0)
        return index, jitter, late, drift

    def _next_frame(self) -> Any:
        buffer = self._producer.buffer
        while not self._stop.is_set():
            try:
                return buffer.get(timeout=0.05)
            except queue.Empty:
                continue
        return END

    def _target_frames(self, index: int, takes: tuple[MotionFrame, ...]) -> list[TargetFrame]:
        """Frame ``index`` for each route, retargeted once per retarget key (the producer's thread)."""
        time_s = index / self.fps
        values_by_key: dict[str, np.ndarray] = {}
        frames = []
        for route in self.routes:
            if route.retarget is None:
                values = _NO_VALUES
            else:
                key = route.retarget_key or str(id(route))
                if key not in values_by_key:
                    values_by_key[key] = route.retarget(takes[0])
                values = values_by_key[key]
            frames.append(TargetFrame(index=index, time=time_s, values=values, takes=takes))
        return frames

    @staticmethod
    def _dispatch(frames: list[TargetFrame], workers: list[BackendWorker], dispatched: float) -> None:
        for w, frame in zip(workers, frames):
            w.slot.put(dataclasses.replace(frame, dispatched=dispatched) if dispatched else frame)

    def _install_signal_handlers(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}
        previous: dict[int, Any] = {}

        def handler(signum: int, _frame: FrameType | None) -> None:
            name = signal.Signals(signum).name
            if self._stop.is_set() or self._clock_done:
                if not self._hurried:
                    log.warning("%s again: stopping at once (waiting frames dropped, servo torque cut)", name)
                    self.hurry()
                return
            self.stop_signal = name
            log.warning("%s: stopping; finishing the outputs (send it again to stop at once)", name)
            self.request_stop()

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, handler)
        return previous

    @staticmethod
    def _restore_signal_handlers(previous: dict[int, Any]) -> None:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _safe_call(fn: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    try:
        return fn()
    except Exception as exc:
        return {"error": error_line(exc)}
