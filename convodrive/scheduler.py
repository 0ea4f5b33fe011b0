"""The 30 fps scheduler (DESIGN, "Scheduler"): one clock, a producer, one worker per backend.

- The generator runs in a producer thread that fills a bounded buffer, so generation runs ahead of
  the clock but never without bound.
- The clock dispatches frame k at the absolute deadline ``t0 + k / fps`` on the monotonic clock, so
  lateness never accumulates into drift. Offline runs use a simulated clock (frame k is at k / fps)
  and go as fast as the slowest consumer allows.
- Each backend has its own worker thread. In real time a real-time backend (hardware, a live
  window) is fed through a latest-value slot: a slow or failing backend drops its own frames and
  never stalls the clock or the others; a file backend is fed through a non-blocking backlog, so
  it receives every frame, late if it must. Offline every backend is fed through a small blocking
  queue, because every frame must arrive and there is no wall clock to protect.
- SIGINT and SIGTERM stop the clock; every backend is still closed, from its own worker, so its
  outputs end complete.
"""

from __future__ import annotations

import collections
import dataclasses
import contextlib
import os
import queue
import signal
import threading
import sys
import time
from types import FrameType
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from convodrive import FPS
from convodrive.backends.base import Backend
from convodrive.motion.clip import MotionFrame
from convodrive.targets import TargetFrame

FrameSource = Iterator[tuple[MotionFrame, ...]]
"""Yields, for each frame index in order, one MotionFrame per take."""
Retarget = Callable[[MotionFrame], np.ndarray]

_END = object()
_MAX_CONSECUTIVE_ERRORS = 90
"""A backend that raised on 3 s of consecutive frames is marked failed and no longer called."""


@dataclasses.dataclass
class Route:
    """A backend and the retargeter that turns canonical motion into its joint values."""

    backend: Backend
    retarget: Retarget | None = None
    """None for backends that take canonical motion only; then ``values`` is empty."""
    retarget_key: str = ""
    """Routes with equal keys share one retargeting per frame."""


class DropOldestSlot:
    """A mailbox that never blocks the clock: past ``capacity`` unread frames the oldest go.

    Two sizes serve two kinds of backend in a real-time run. A real-time backend (hardware, a live
    window) gets ``LATEST_CAPACITY``: a slow one skips to the newest frames, never more than 100 ms
    behind; 3 rather than 1 lets a backend that keeps up absorb the frames the clock sends back to
    back after the OS held the process past a deadline (a stall of up to 100 ms). A file backend (recorder, video) gets
    ``BACKLOG_CAPACITY``: it receives every frame, late if it must, without slowing the clock.
    ``close`` lets the reader take what is left, then the end of the run.
    """

    LATEST_CAPACITY = 3
    BACKLOG_CAPACITY = 9000  # 5 minutes at 30 fps

    def __init__(self, capacity: int) -> None:
        self._cond = threading.Condition()
        self._items: collections.deque[Any] = collections.deque()
        self._capacity = capacity
        self._closed = False
        self.dropped = 0

    def put(self, item: Any) -> None:
        with self._cond:
            self._items.append(item)
            if len(self._items) > self._capacity:
                self._items.popleft()
                self.dropped += 1
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()

    def get(self) -> Any:
        with self._cond:
            while not self._items and not self._closed:
                self._cond.wait()
            return self._items.popleft() if self._items else _END


class BlockingSlot:
    """A small FIFO for offline runs: every frame is delivered; a slow backend slows the run."""

    def __init__(self, size: int = 8) -> None:
        self._q: queue.Queue[Any] = queue.Queue(maxsize=size)
        self.dropped = 0

    def put(self, item: Any) -> None:
        self._q.put(item)

    def close(self) -> None:
        self._q.put(_END)

    def get(self) -> Any:
        return self._q.get()


@dataclasses.dataclass
class BackendStats:
    name: str
    sent: int = 0
    dropped: int = 0
    errors: int = 0
    last_error: str = ""
    failed: bool = False
    close_error: str = ""
    send_seconds: list[float] = dataclasses.field(default_factory=list)
    health_events: list[dict[str, Any]] = dataclasses.field(default_factory=list)


class BackendWorker(threading.Thread):
    """Runs one backend: sends what arrives in its slot, and closes it when the run ends."""

    def __init__(self, route: Route, realtime: bool, clock: Callable[[], float]) -> None:
        super().__init__(name=f"backend-{route.backend.name}", daemon=True)
        self.route = route
        self.slot: DropOldestSlot | BlockingSlot
        if not realtime:
            self.slot = BlockingSlot()
        elif route.backend.realtime:
            self.slot = DropOldestSlot(DropOldestSlot.LATEST_CAPACITY)
        else:
            self.slot = DropOldestSlot(DropOldestSlot.BACKLOG_CAPACITY)
        self.stats = BackendStats(route.backend.name)
        self._clock = clock
        self._last_status = "ok"

    def run(self) -> None:
        backend = self.route.backend
        consecutive = 0
        try:
            while True:
                item = self.slot.get()
                if item is _END:
                    break
                if self.stats.failed:
                    self.stats.dropped += 1
                    continue
                start = time.perf_counter()
                try:
                    backend.send(item)
                    consecutive = 0
                    self.stats.sent += 1
                except Exception as exc:  # a backend fault degrades this backend only
                    consecutive += 1
                    self.stats.errors += 1
                    self.stats.last_error = f"{exc.__class__.__name__}: {exc}"
                    if consecutive >= _MAX_CONSECUTIVE_ERRORS:
                        self.stats.failed = True
                        self._event("failed", self.stats.last_error)
                finally:
                    self.stats.send_seconds.append(time.perf_counter() - start)
                self._watch_health()
        finally:
            self.close_backend()

    def close_backend(self) -> None:
        try:
            self.route.backend.close()
        except Exception as exc:
            self.stats.close_error = f"{exc.__class__.__name__}: {exc}"
            self._event("close-error", self.stats.close_error)
        self.stats.dropped += self.slot.dropped

    def _watch_health(self) -> None:
        if self.stats.sent % 30:
            return
        try:
            status = str(self.route.backend.health().get("status", "ok"))
        except Exception as exc:
            status = f"health-error: {exc}"
        if status != self._last_status:
            self._event(status, "")
            self._last_status = status

    def _event(self, status: str, detail: str) -> None:
        self.stats.health_events.append({"time": round(self._clock(), 3), "status": status, "detail": detail})


@dataclasses.dataclass
class RunResult:
    """Everything the run report is made of; see ``convodrive.report``."""

    mode: str
    frames: int
    expected_frames: int | None
    wall_seconds: float
    clock_seconds: float
    """From the first frame's deadline to one period after the last dispatch: the clock's own span."""
    jitter_ms: list[float]
    late_frames: int
    generator_seconds: float
    audio_seconds: float
    drift_frames: float
    interrupted: bool
    backends: list[BackendStats]
    backend_reports: dict[str, dict[str, Any]]
    backend_health: dict[str, dict[str, Any]]
    clock_priority: str = "normal"


class Producer(threading.Thread):
    """Pulls frames from the generator into a bounded buffer and times the generator."""

    def __init__(self, source: FrameSource, buffer_frames: int) -> None:
        super().__init__(name="generator", daemon=True)
        self.source = source
        self.buffer: queue.Queue[Any] = queue.Queue(maxsize=buffer_frames)
        self.generator_seconds = 0.0
        self.error: BaseException | None = None
        self.stop_event = threading.Event()

    def run(self) -> None:
        try:
            while not self.stop_event.is_set():
                start = time.perf_counter()
                try:
                    takes = next(self.source)
                except StopIteration:
                    break
                finally:
                    self.generator_seconds += time.perf_counter() - start
                self._put(takes)
        except BaseException as exc:  # handed to the clock thread, which re-raises it
            self.error = exc
        finally:
            self._put(_END, force=True)

    def _put(self, item: Any, force: bool = False) -> None:
        while True:
            if self.stop_event.is_set() and not force:
                return
            try:
                self.buffer.put(item, timeout=0.05)
                return
            except queue.Full:
                if force and self.stop_event.is_set():
                    try:  # make room for the end marker: nobody reads the rest anyway
                        self.buffer.get_nowait()
                    except queue.Empty:
                        pass


class Scheduler:
    """Drives ``routes`` from ``source`` at ``fps``; ``run`` returns a ``RunResult``."""

    def __init__(
        self,
        source: FrameSource,
        routes: Sequence[Route],
        *,
        realtime: bool,
        fps: float = FPS,
        expected_frames: int | None = None,
        audio_seconds: float | None = None,
        buffer_frames: int = 30,
        on_frame: Callable[[int], None] | None = None,
        on_start: Callable[[], None] | None = None,
        start_delay: float = 0.05,
        spin_seconds: float = 0.002,
    ) -> None:
        self.routes = list(routes)
        self.realtime = realtime
        self.fps = float(fps)
        self.expected_frames = expected_frames
        self.audio_seconds = audio_seconds
        self.on_frame = on_frame
        self.on_start = on_start
        self.start_delay = start_delay
        self.spin_seconds = spin_seconds
        self._producer = Producer(source, buffer_frames)
        self._stop = threading.Event()
        self._interrupted = False
        self._t0 = 0.0
        self.clock_priority = "normal"
        self._clock_seconds = 0.0

    def request_stop(self) -> None:
        """Stop at the next frame boundary (what SIGINT and SIGTERM do)."""
        self._interrupted = True
        self._stop.set()

    def run(self) -> RunResult:
        previous = self._install_signal_handlers()
        workers = [BackendWorker(r, self.realtime, self._elapsed) for r in self.routes]
        wall_start = time.monotonic()
        jitter: list[float] = []
        late = 0
        frames = 0
        drift = 0.0
        try:
            with _realtime_priority(self.realtime) as self.clock_priority:
                for w in workers:
                    w.start()
                self._producer.start()
                frames, jitter, late, drift = self._clock_loop(workers)
            if self._producer.error is not None and not isinstance(self._producer.error, KeyboardInterrupt):
                raise self._producer.error
        finally:
            self._producer.stop_event.set()
            for w in workers:
                w.slot.close()
            for w in workers:
                if w.is_alive() or w.ident is not None:
                    w.join()
                else:  # never started (interrupted at once): its backend still must close
                    w.close_backend()
            self._restore_signal_handlers(previous)
        wall = time.monotonic() - wall_start
        return RunResult(
            mode="realtime" if self.realtime else "offline",
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
        )

    def _elapsed(self) -> float:
        return time.monotonic() - self._t0 if self._t0 else 0.0

    def _clock_loop(self, workers: list[BackendWorker]) -> tuple[int, list[float], int, float]:
        """Dispatch frames until the source ends or a stop is requested.

        A frame that reaches the clock after its deadline is late: it goes out at once and the
        next deadlines stay where they were, so the clock catches up instead of drifting.
        """
        jitter: list[float] = []
        late = 0
        index = 0
        period = 1.0 / self.fps
        last_dispatch = 0.0
        while True:
            item = self._next_frame()
            if item is _END:
                break
            if index == 0:  # the clock starts once the first frame exists
                self._t0 = time.monotonic() + self.start_delay
                if self.on_start is not None:
                    self.on_start()
            if self.realtime:
                deadline = self._t0 + index * period
                if time.monotonic() > deadline:
                    late += 1
                else:
                    _sleep_until(deadline, self.spin_seconds)
                last_dispatch = time.monotonic()
                jitter.append((last_dispatch - deadline) * 1000.0)
            self._dispatch(index, item, workers)
            if self.on_frame is not None:
                self.on_frame(index)
            index += 1
        drift = 0.0
        if index:
            end = last_dispatch if self.realtime else time.monotonic()
            self._clock_seconds = max(end - self._t0, 0.0) + (period if self.realtime else 0.0)
        if self.realtime and index:
            drift = (last_dispatch - self._t0) * self.fps - (index - 1)
        return index, jitter, late, drift

    def _next_frame(self) -> Any:
        buffer = self._producer.buffer
        while not self._stop.is_set():
            try:
                return buffer.get(timeout=0.05)
            except queue.Empty:
                continue
        return _END

    def _dispatch(self, index: int, takes: tuple[MotionFrame, ...], workers: list[BackendWorker]) -> None:
        time_s = index / self.fps
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
            w.slot.put(TargetFrame(index=index, time=time_s, values=values, takes=takes))

    def _install_signal_handlers(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}
        previous = {}

        def handler(signum: int, _frame: FrameType | None) -> None:
            self.request_stop()

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, handler)
        return previous

    @staticmethod
    def _restore_signal_handlers(previous: dict[int, Any]) -> None:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _sleep_until(deadline: float, spin_seconds: float) -> None:
    """Sleep to ``spin_seconds`` before ``deadline``, then yield-spin to it.

    A sleeping thread wakes when the OS gets round to it, which under load is a millisecond or
    two late; waking early and spinning the rest absorbs that. ``time.sleep(0)`` in the spin lets
    other threads have the GIL. The cost is ``spin_seconds`` of one core per frame (6 % at 2 ms).
    """
    remaining = deadline - time.monotonic()
    if remaining > spin_seconds:
        time.sleep(remaining - spin_seconds)
    while time.monotonic() < deadline:
        time.sleep(0)


@contextlib.contextmanager
def _realtime_priority(realtime: bool) -> Iterator[str]:
    """Help the clock and the backend workers wake on time during a real-time run.

    Two things delay a wake-up past its deadline: the OS giving the CPU to another process, and
    another Python thread holding the GIL for up to the switch interval (5 ms by default). We
    shorten the switch interval to 0.5 ms, and raise this thread's scheduling weight (nice -10,
    granted to root or with CAP_SYS_NICE); threads started inside inherit it, so the workers get
    it too. Unlike a real-time policy this cannot starve the machine if a backend spins. Both are
    restored afterwards. CONVODRIVE_NO_RENICE=1 skips the priority change.
    """
    if not realtime:
        yield "offline"
        return
    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)
    old_nice = None
    granted = "normal"
    if hasattr(os, "setpriority") and not os.environ.get("CONVODRIVE_NO_RENICE"):
        try:
            old_nice = os.getpriority(os.PRIO_PROCESS, 0)
            if old_nice > -10:
                os.setpriority(os.PRIO_PROCESS, 0, -10)
                granted = "nice -10"
        except (PermissionError, OSError):
            old_nice = None
    try:
        yield granted
    finally:
        sys.setswitchinterval(old_interval)
        if old_nice is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, old_nice)
            except OSError:
                pass


_NO_VALUES = np.zeros(0)
_NO_VALUES.setflags(write=False)


def _safe_call(fn: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    try:
        return fn()
    except Exception as exc:
        return {"error": f"{exc.__class__.__name__}: {exc}"}
