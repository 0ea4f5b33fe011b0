"""Scheduling weight for paced runs: the clock and its workers should wake on time."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator


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
