"""An emulated Dynamixel head in a process of its own, as real servos sit outside the driver's
process: what ``convodrive demo`` drives when there is no robot."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from collections.abc import Iterable, Iterator
from multiprocessing.connection import Connection

from convodrive.backends.servo.dynamixel_emulator import start_emulated_head
from convodrive.backends.servo.emulator_faults import Fault, parse_fault
from convodrive.plumbing.priority import EMULATOR_FIFO_PRIORITY


@contextlib.contextmanager
def emulated_head_process(faults: Iterable[str] = (), ids: Iterable[int] = range(1, 8)) -> Iterator[str]:
    """An emulated head served by a process of its own, as real servos sit outside the driver's
    process (so it takes no GIL time from the driver's clock); yields its port path.

    It ignores SIGINT and SIGTERM, so that a driver stopped by Ctrl-C can still ease the head to
    neutral and switch its torque off; it stops when the context ends or the driver's process dies.
    ``faults`` use the ``--fault`` grammar (``parse_fault``).
    """
    from convodrive.plumbing.child import start_child

    process, conn = start_child(_serve_head, list(ids), [parse_fault(text) for text in faults])
    try:
        if not conn.poll(60.0):
            raise RuntimeError("the emulated servo head did not start within 60 s")
        yield str(conn.recv())
    finally:
        conn.close()  # the emulator's end sees EOF and stops
        try:
            process.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _serve_head(conn: Connection, ids: list[int], faults: list[Fault]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    # The serving thread answers at real-time priority (``PtyServer``); the process's other threads
    # share its interpreter lock, so they get that priority too: one of them preempted while it held
    # the lock kept a reply back as long as the driver's real-time threads held the core.
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(EMULATOR_FIFO_PRIORITY))
    except (AttributeError, OSError):
        try:
            os.nice(-10)
        except OSError:
            pass
    with start_emulated_head(ids, faults=faults) as head:
        conn.send(head.port)
        try:
            conn.recv()
        except (EOFError, OSError):
            pass
