"""The scheduler's loop (DESIGN, "Scheduler"): one clock, a producer, one worker per backend.

- The generator runs in a producer thread that fills a bounded buffer, so generation runs ahead of
  the clock but never without bound.
- Frame k is due at ``k / fps`` on the run's clock (``convodrive.scheduler.clock``). A frame that
  reaches the clock after its deadline goes out at once and the next deadlines stay where they
  were, so lateness never accumulates into drift.
- Each backend has its own worker. On a paced clock a real-time backend (hardware, a live window)
  is fed through a latest-value slot, so a slow or failing backend drops its own frames and never
  stalls the clock or the others; a file backend gets a non-blocking backlog, so it receives every
  frame, late if it must. On a simulated clock every backend gets a small blocking queue.
- SIGINT and SIGTERM stop the clock; every backend is still closed, from its own worker, so its
  outputs end complete.
"""

from __future__ import annotations

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
from convodrive.plumbing.errors import UserError
from convodrive.scheduler.clock import Clock
from convodrive.scheduler.priority import realtime_priority
from convodrive.scheduler.producer import FrameSource, Producer
from convodrive.scheduler.report import RunResult
from convodrive.scheduler.route import Route
from convodrive.scheduler.slots import END
from convodrive.scheduler.workers import BackendWorker, OnSent

_NO_VALUES = np.zeros(0)
_NO_VALUES.setflags(write=False)


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
        self.start_delay = start_delay
        self._producer = Producer(source, buffer_frames)
        self._stop = threading.Event()
        self._interrupted = False
        self._started = False
        self.clock_priority = "normal"
        self._clock_seconds = 0.0

    def request_stop(self) -> None:
        """Stop at the next frame boundary (what SIGINT and SIGTERM do)."""
        self._interrupted = True
        self._stop.set()

    def run(self) -> RunResult:
        previous = self._install_signal_handlers()
        paced = self.clock.paced
        workers = [BackendWorker(r, paced, self._elapsed, self.on_sent) for r in self.routes]
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
                frames, jitter, late, drift = self._clock_loop(workers)
            error = self._producer.error
            if isinstance(error, UserError):  # the input ended the run (audio that stopped decoding)
                input_error = str(error)
            elif error is not None and not isinstance(error, KeyboardInterrupt):
                raise error
        finally:
            self._producer.stop_event.set()
            for w in workers:
                w.slot.close()
            for w in workers:
                if w.is_alive() or w.ident is not None:
                    w.join()
                else:  # never started (interrupted at once): its backend still must close
                    w.close_backend()
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
            backends=[w.stats for w in workers],
            backend_reports={w.stats.name: _safe_call(w.route.backend.report) for w in workers},
            backend_health={w.stats.name: _safe_call(w.route.backend.health) for w in workers},
            clock_priority=self.clock_priority,
            input_error=input_error,
        )

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
            self._dispatch(index, item, workers)
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

    def _dispatch(self, index: int, takes: tuple[MotionFrame, ...], workers: list[BackendWorker]) -> None:
        time_s = index / self.fps
        dispatched = time.monotonic() if self.clock.paced else 0.0
        values_by_key: dict[str, np.ndarray] = {}
        for w in workers:
            route = w.route
            if route.retarget is None:
                values = _NO_VALUES
            else:
                key = route.retarget_key or str(id(route))
                if key not in values_by_key:
                    values_by_key[key] = route.retarget(takes[0])
                values = values_by_key[key]
            w.slot.put(TargetFrame(index=index, time=time_s, values=values, takes=takes, dispatched=dispatched))

    def _install_signal_handlers(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}
        previous: dict[int, Any] = {}

        def handler(signum: int, _frame: FrameType | None) -> None:
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
        return {"error": f"{exc.__class__.__name__}: {exc}"}
