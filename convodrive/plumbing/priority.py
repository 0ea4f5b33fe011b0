"""Scheduling weight for paced runs: the clock, its workers, the live audio callbacks and the
emulated devices' serving threads should wake on time."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from collections.abc import Iterator

log = logging.getLogger(__name__)

CLOCK_FIFO_PRIORITY = 10
"""The clock thread's real-time priority when it may have one (1..99; low: it only needs to beat
ordinary processes, not the kernel's own real-time threads)."""
HELPER_FIFO_PRIORITY = CLOCK_FIFO_PRIORITY - 1
"""The producer's and light workers' real-time priority: above every ordinary process, below the
clock, so the clock still preempts them when it wakes."""

EMULATOR_FIFO_PRIORITY = CLOCK_FIFO_PRIORITY + 1
"""An emulated device's serving thread: above the driver's clock and helpers. Servos answer whatever
the host's CPU does; below the helpers, two real-time threads of the driver (or of another paced
run) holding both cores kept a reply back for a quarter of a second, and the driver counted the
servo lost. Its work is a packet's parse and reply, well under a millisecond, so the clock loses no
more than that."""

_FIFO_INHERITED = getattr(os, "SCHED_FIFO", 1)
"""Real-time, inherited by the threads and processes the thread starts."""
_FIFO = _FIFO_INHERITED | getattr(os, "SCHED_RESET_ON_FORK", 0)
"""Real-time, and not inherited: a thread or process a helper starts (an ONNX Runtime pool, an
ffmpeg decoder) gets ordinary scheduling."""


@contextlib.contextmanager
def realtime_priority(paced: bool) -> Iterator[str]:
    """Help the clock and the backend workers wake on time during a real-time run.

    Two things delay a wake-up past its deadline: the OS giving the CPU to another process, and
    another Python thread holding the GIL for up to the switch interval (5 ms by default). We
    shorten the switch interval to 0.5 ms, and raise this thread's scheduling weight (nice -10,
    granted to root or with CAP_SYS_NICE); threads started inside inherit it, so the workers get
    it too. Unlike a real-time policy this cannot starve the machine if a backend spins. Both are
    restored afterwards. CONVODRIVE_NO_RENICE=1 skips the priority change.
    """
    if not paced:
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


@contextlib.contextmanager
def clock_thread_priority(paced: bool) -> Iterator[str | None]:
    """Give the calling thread (the clock's) a real-time policy while it paces frames.

    With the CPU busy (a renderer, a simulator, other people's work on a 2-core machine) even a
    heavily weighted ordinary thread waits for a time slice: 5 to 20 ms late wake-ups. A thread
    under SCHED_FIFO runs as soon as it wakes. It is safe here because the clock thread only waits
    and hands frames out (well under 1 % of a core), and it is set after the workers and the
    producer started, so none of them inherits it. Needs root, CAP_SYS_NICE or an rtprio limit;
    otherwise nothing changes. Yields the policy granted, or None.
    """
    if not paced or not hasattr(os, "sched_setscheduler") or os.environ.get("CONVODRIVE_NO_RENICE"):
        yield None
        return
    try:
        old_policy = os.sched_getscheduler(0)
        old_param = os.sched_getparam(0)
        # Inherited, unlike the helpers': the audio threads a playback clock starts from here
        # (PortAudio's callback) must run as promptly as the clock that reads their position.
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(CLOCK_FIFO_PRIORITY))
    except (PermissionError, OSError):
        yield None
        return
    try:
        yield f"SCHED_FIFO {CLOCK_FIFO_PRIORITY}"
    finally:
        try:
            os.sched_setscheduler(0, old_policy, old_param)
        except OSError:
            pass


class HelperPriority:
    """SCHED_FIFO just below the clock for a thread of the clock's process with little work a frame.

    The clock thread wakes on time under SCHED_FIFO, but then needs the interpreter lock. Measured
    on a loaded 2-core machine, the late wake-ups (8 to 46 ms) were the clock waiting for the lock
    held by the producer or a worker that the OS had preempted to run other processes, 20 to 200 ms
    on the run queue while holding it. A thread here at real-time priority is never preempted by an
    ordinary process, so whatever it holds, it lets go within the switch interval.

    Real-time priority can starve the machine, so it is given only to bounded work (the producer,
    which never runs more than its buffer ahead, and workers whose ``send`` is light) and only while
    that work stays small: a thread that used more than ``MAX_SHARE`` of a ``WINDOW_S`` window of
    CPU time (a generator slower than real time, a backend slower than it said) goes back to
    ordinary scheduling for the rest of the run. Waiting (for audio, for a child's answer) is not
    work: the share is the thread's CPU time. Use it as a context manager in the thread itself and
    call ``tick`` after each piece of work.

    Threads the helper starts get ordinary scheduling (an ONNX Runtime pool), unless ``inherit``:
    a servo child's supervisor holds the bus and the interpreter lock that its frames wait for, so
    it must not be preempted either.
    """

    MAX_SHARE = 0.5
    WINDOW_S = 1.0

    def __init__(self, paced: bool, who: str, *, inherit: bool = False, priority: int = HELPER_FIFO_PRIORITY) -> None:
        self.paced = paced
        self.who = who
        self.inherit = inherit
        self.priority = priority
        self.active = False
        self.demoted = False
        self._old: tuple[int, os.sched_param] | None = None
        self._window_start = 0.0
        self._cpu_start = 0.0

    def __enter__(self) -> HelperPriority:
        if not self.paced or not hasattr(os, "sched_setscheduler") or os.environ.get("CONVODRIVE_NO_RENICE"):
            return self
        policy = _FIFO_INHERITED if self.inherit else _FIFO
        try:
            self._old = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, policy, os.sched_param(self.priority))
        except (PermissionError, OSError):
            self._old = None
            return self
        self.active = True
        self._window_start, self._cpu_start = time.monotonic(), time.thread_time()
        return self

    def tick(self) -> None:
        """After a piece of work: leave real-time priority if this thread's CPU share is too much."""
        if not self.active:
            return
        now = time.monotonic()
        window = now - self._window_start
        if window < self.WINDOW_S:
            return
        cpu = time.thread_time()
        share = (cpu - self._cpu_start) / window
        self._window_start, self._cpu_start = now, cpu
        if share > self.MAX_SHARE:
            self._restore()
            self.demoted = True
            log.info(
                "%s: used %.0f %% of a core, too much for real-time priority; back to ordinary scheduling (thread %s)",
                self.who,
                100 * share,
                threading.current_thread().name,
            )

    def __exit__(self, *exc: object) -> None:
        self._restore()

    def _restore(self) -> None:
        if self.active and self._old is not None:
            try:
                os.sched_setscheduler(0, self._old[0], self._old[1])
            except OSError:
                pass
        self.active = False


class CallbackPriority:
    """``HelperPriority`` for a thread another library owns and calls us from (PortAudio's audio
    callback): taken on the first call, its CPU share checked on every later one.

    A live run's clock is the speaker's position, and the capture of the partner and the monitor
    are stamped by their callbacks. A callback thread at ordinary priority waited behind other
    processes on a loaded machine, the server ran out of samples (underflows), and the time line
    moved under the clock. The work a call is a block's copy, so real-time priority costs nothing.
    """

    def __init__(self, who: str) -> None:
        self.helper = HelperPriority(True, who)
        self._taken = False

    @property
    def granted(self) -> str:
        """What the thread has, for a report."""
        if self.helper.demoted:
            return "normal (too much work a call for real time)"
        return f"SCHED_FIFO {self.helper.priority}" if self.helper.active else "normal"

    def __call__(self) -> None:
        if self._taken:
            self.helper.tick()
            return
        self._taken = True
        self.helper.__enter__()
