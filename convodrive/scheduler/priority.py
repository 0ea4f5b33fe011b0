"""Scheduling weight for paced runs: the clock and its workers should wake on time."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

CLOCK_FIFO_PRIORITY = 10
"""The clock thread's real-time priority when it may have one (1..99; low: it only needs to beat
ordinary processes, not the kernel's own real-time threads)."""


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
