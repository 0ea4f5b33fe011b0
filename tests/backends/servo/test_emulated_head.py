"""The emulated devices stand for servos, which do not share the host's CPU: they answer on time while
the driver's real-time threads hold their core (the demo's head in a process of its own, and every
emulator's serving thread wherever it runs: a test's, ``convodrive emulate``'s)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.conftest import needs_realtime, require

pytestmark = require("hardware")

from convodrive.backends.servo.dynamixel_bus import DynamixelBus, Motor  # noqa: E402
from convodrive.backends.servo.dynamixel_emulator import start_emulated_head  # noqa: E402
from convodrive.backends.servo.dynamixel_table import model  # noqa: E402
from convodrive.backends.servo.emulated_head import emulated_head_process  # noqa: E402
from convodrive.backends.servo.feetech_emulator import start_emulated_feetech  # noqa: E402
from convodrive.backends.servo.maestro_emulator import start_emulated_maestro  # noqa: E402
from convodrive.backends.servo.pty_server import PtyDevice  # noqa: E402
from convodrive.plumbing.priority import CLOCK_FIFO_PRIORITY, EMULATOR_FIFO_PRIORITY, HELPER_FIFO_PRIORITY  # noqa: E402

HOG = """
import os, sys, time
os.sched_setaffinity(0, {int(sys.argv[1])})
os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(sys.argv[2])))
print("holding", flush=True)
end = time.monotonic() + float(sys.argv[3])
while time.monotonic() < end:
    pass
"""
"""A thread of the driver at real-time priority that holds one core for a while (a producer at
work, bounded by ``HelperPriority``'s share but not by its length)."""

LATENCY_MS = 100.0
"""The bus's USB latency allowance, so a read gives up after about 200 ms: far under the 3 s an
emulator that waited for its core would take, and over what the kernel itself adds. The emulator's
bytes reach the bus through the pty's ``flush_to_ldisc``, an ordinary-class kworker; woken on the
held core it waits until the idle core pulls it over: 40-82 ms for 6 of 365 replies in 12 runs
(kernel 6.18, traced), where 16 ms (a 34 ms timeout) failed half the runs. A servo's reply crosses
no pty."""


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _pin(pid: int, cpu: int) -> None:
    for task in Path(f"/proc/{pid}/task").iterdir():
        os.sched_setaffinity(int(task.name), {cpu})


@needs_realtime
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs a second core for the driver")
def test_the_emulated_head_answers_while_the_drivers_realtime_threads_hold_its_core() -> None:
    before, cpus = set(_children(os.getpid())), os.sched_getaffinity(0)
    with emulated_head_process(ids=range(1, 4)) as port:
        (emulator,) = set(_children(os.getpid())) - before
        held, free = sorted(cpus)[:2]
        _pin(emulator, held)
        os.sched_setaffinity(0, {free})
        bus = DynamixelBus(port, [Motor(f"m{i}", i, model("xl330")) for i in range(1, 4)], latency_ms=LATENCY_MS)
        bus.connect()
        hog = subprocess.Popen(
            [sys.executable, "-c", HOG, str(held), str(HELPER_FIFO_PRIORITY), "3"], stdout=subprocess.PIPE, text=True
        )
        try:
            assert hog.stdout is not None and hog.stdout.readline().strip() == "holding"
            # The bus from the driver's servo process, at the helpers' priority on the other core.
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(HELPER_FIFO_PRIORITY))
            for _ in range(5):  # 5 x 3 reads while the core is held (at most 3 s: stopped after them)
                for motor in ("m1", "m2", "m3"):
                    bus.read("Present_Position", motor)
            timeouts = sum(bus.health[m].timeouts for m in ("m1", "m2", "m3"))
            assert timeouts == 0, f"{timeouts} replies timed out: the emulator waited for its core"
            assert hog.poll() is None, "the core was held throughout"
        finally:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            hog.kill()
            hog.wait(timeout=10)
            os.sched_setaffinity(0, cpus)
            bus.disconnect()


def _realtime_threads() -> dict[int, int]:
    """This process's threads under SCHED_FIFO, with their priorities."""
    found = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            if os.sched_getscheduler(int(task.name)) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO:
                found[int(task.name)] = os.sched_getparam(int(task.name)).sched_priority
        except OSError:
            continue  # a thread that ended meanwhile
    return found


@needs_realtime
@pytest.mark.parametrize("start", [start_emulated_head, start_emulated_feetech, start_emulated_maestro])
def test_every_emulator_serves_from_a_thread_above_the_drivers_clock(start: Callable[[], PtyDevice]) -> None:
    before = _realtime_threads()
    with start():
        for _ in range(100):  # the serving thread takes its priority as it starts
            serving = {tid: p for tid, p in _realtime_threads().items() if tid not in before}
            if serving:
                break
            time.sleep(0.01)
    assert list(serving.values()) == [EMULATOR_FIFO_PRIORITY] and EMULATOR_FIFO_PRIORITY > CLOCK_FIFO_PRIORITY
