"""The scheduler's contract: absolute deadlines, per-backend isolation, offline delivery, reports."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bench.bench_scheduler import run_bench
from convodrive.backends.base import Session
from convodrive.scheduler import DropOldestSlot, MonotonicClock, Route, Scheduler, SimulatedClock
from convodrive.scheduler.report import backend_state, build_report, summarize
from tests.conftest import needs_realtime
from tests.doubles import CountingBackend, FailingBackend, SlowBackend, neutral_frames


def _open(backends, tmp_path: Path, offline: bool):
    for b in backends:
        b.open(b.spec, Session(out_dir=tmp_path, offline=offline))
    return [Route(b) for b in backends]


def test_slow_and_failing_backends_never_stall_the_clock_or_the_others(tmp_path: Path) -> None:
    fast = CountingBackend({"name": "fast"})
    slow = SlowBackend({"name": "slow", "delay": 0.2})
    failing = FailingBackend({"name": "failing"})
    frames = 45  # 1.5 s of wall clock
    result = Scheduler(
        neutral_frames(frames), _open([fast, slow, failing], tmp_path, False), clock=MonotonicClock()
    ).run()

    assert result.frames == frames
    assert fast.indices == list(range(frames)), "the fast backend must get every frame, in order"
    assert 0 < len(slow.indices) < frames // 2, "the slow backend drops its own frames"
    assert slow.indices[-1] == frames - 1, "the slow backend still ends on the newest frame"
    stats = {s.name: s for s in result.backends}
    assert stats["slow"].dropped == frames - len(slow.indices)
    assert stats["failing"].errors == frames and "port vanished" in stats["failing"].last_error
    # 45 frames at 30 fps take 1.5 s; a stalled clock would take 45 x 0.2 s = 9 s.
    assert result.wall_seconds < 4.0
    assert all(b.closed for b in (fast, slow, failing))


def test_offline_delivers_every_frame_to_every_backend_without_sleeping(tmp_path: Path) -> None:
    fast = CountingBackend({"name": "fast"})
    slow = SlowBackend({"name": "slow", "delay": 0.01})
    frames = 300  # 10 s of motion
    result = Scheduler(neutral_frames(frames), _open([fast, slow], tmp_path, True), clock=SimulatedClock()).run()
    assert fast.indices == list(range(frames))
    assert slow.indices == list(range(frames))
    assert result.wall_seconds < 8.0, "offline runs use a simulated clock, not the wall clock"
    assert result.jitter_ms == [] and result.late_frames == 0


def test_request_stop_closes_every_backend(tmp_path: Path) -> None:
    fast = CountingBackend({"name": "fast"})
    scheduler = Scheduler(
        neutral_frames(10_000),
        _open([fast], tmp_path, False),
        clock=MonotonicClock(),
        on_start=lambda: threading.Timer(0.3, scheduler.request_stop).start(),  # timed from the clock's start
    )
    result = scheduler.run()
    assert result.interrupted
    assert 0 < result.frames < 100
    assert fast.closed and fast.indices == list(range(result.frames))


def test_generator_error_reaches_the_caller_and_backends_still_close(tmp_path: Path) -> None:
    def broken():
        yield from neutral_frames(5)
        raise RuntimeError("model exploded")

    fast = CountingBackend({"name": "fast"})
    with pytest.raises(RuntimeError, match="model exploded"):
        Scheduler(broken(), _open([fast], tmp_path, True), clock=SimulatedClock()).run()
    assert fast.closed and fast.indices == list(range(5))


def test_latest_slot_keeps_the_newest_and_counts_drops() -> None:
    slot = DropOldestSlot(DropOldestSlot.LATEST_CAPACITY)
    for i in range(5):
        slot.put(i)
    slot.close()
    assert [slot.get(), slot.get(), slot.get()] == [2, 3, 4]
    assert slot.dropped == 2
    end = slot.get()
    assert end not in (2, 3, 4) and slot.get() is end  # the end marker follows the last frame


def test_file_backends_in_a_real_time_run_get_every_frame(tmp_path: Path) -> None:
    """A recorder beside a servo head: the head skips frames it cannot keep up with, the file does not."""
    head = SlowBackend({"name": "head", "delay": 0.1})
    head.realtime = True
    recorder = SlowBackend({"name": "recorder", "delay": 0.05})
    recorder.realtime = False
    frames = 30
    result = Scheduler(neutral_frames(frames), _open([head, recorder], tmp_path, False), clock=MonotonicClock()).run()
    assert recorder.indices == list(range(frames))
    assert len(head.indices) < frames and head.indices[-1] == frames - 1
    assert abs(result.drift_frames) < 1.0


def test_report_has_the_figures_and_a_readable_summary(tmp_path: Path) -> None:
    fast = CountingBackend({"name": "fast"})
    result = Scheduler(neutral_frames(20), _open([fast], tmp_path, False), clock=MonotonicClock()).run()
    report = build_report(result, {"generator": {"name": "test"}})
    assert report["frames"] == 20 and report["mode"] == "realtime"
    assert set(report["jitter_ms"]) == {"p50", "p99", "max"}
    assert report["backends"]["fast"]["frames_sent"] == 20
    assert report["backends"]["fast"]["frames_dropped"] == 0
    text = summarize(report)
    assert "20 frames" in text and "jitter" in text and "fast" in text


def test_a_short_run_whose_every_send_failed_reports_failed(tmp_path: Path) -> None:
    """Far fewer errors than the 90 in a row that stop a backend mid-run: the report still says
    FAILED when every send failed, and the run as a whole failed when no backend worked."""
    failing = FailingBackend({"name": "failing"})
    result = Scheduler(neutral_frames(10), _open([failing], tmp_path, True), clock=SimulatedClock()).run()
    report = build_report(result, {})
    assert backend_state(report["backends"]["failing"]) == ("FAILED", "10 of 10 sends failed: OSError: port vanished")
    assert report["every_backend_failed"] is True
    assert "failing    FAILED" in summarize(report)

    fast = CountingBackend({"name": "fast"})
    result = Scheduler(
        neutral_frames(10), _open([FailingBackend({"name": "failing"}), fast], tmp_path, True), clock=SimulatedClock()
    ).run()
    report = build_report(result, {})
    assert report["every_backend_failed"] is False, "one body still moved"
    assert backend_state(report["backends"]["fast"]) == ("ok", "")


@pytest.mark.parametrize(
    ("errors", "sent", "state"), [(0, 30, "ok"), (2, 28, "ok"), (5, 25, "degraded"), (27, 3, "FAILED")]
)
def test_the_share_of_failed_sends_sets_the_state(errors: int, sent: int, state: str) -> None:
    entry = {"errors": errors, "frames_sent": sent, "last_error": "OSError: refused" if errors else ""}
    assert backend_state(entry)[0] == state


def test_short_benchmark_counts() -> None:
    """The 5-second version of bench/bench_scheduler.py: counts, not timings."""
    out = run_bench(5.0, load=True)
    assert out["frames"] == 150
    assert out["frames_lost"]["fast_a"] == 0 and out["frames_lost"]["fast_b"] == 0
    assert out["frames_lost"]["slow"] > 100
    assert abs(out["drift_frames"]) < 1.0


def test_retargeting_runs_once_a_frame_in_order_off_the_clock_thread(tmp_path: Path) -> None:
    """Retargeters are stateful filters: each frame once, in order; and never on the clock's thread."""
    calls: list[tuple[str, float]] = []

    def retarget(frame):
        calls.append((threading.current_thread().name, frame.time))
        return np.array([frame.time])

    got: dict[str, list[float]] = {"a": [], "b": []}

    class Keeper(CountingBackend):
        def send(self, frame):
            got[self.name].append(float(frame.values[0]))

    a, b = Keeper({"name": "a"}), Keeper({"name": "b"})
    routes = [Route(r.backend, retarget, "one profile") for r in _open([a, b], tmp_path, False)]
    Scheduler(neutral_frames(30), routes, clock=MonotonicClock()).run()
    times = [i / 30 for i in range(30)]
    assert [t for _, t in calls] == pytest.approx(times), "once per frame for both routes, in order"
    assert {name for name, _ in calls} == {"generator"}, "the producer's thread retargets, not the clock's"
    assert got["a"] == got["b"] == pytest.approx(times)


def test_backends_finishing_after_the_clock_report_their_progress(tmp_path: Path) -> None:
    """A video lags a real-time run; once the clock ends, the caller hears how much is left."""
    writer = SlowBackend({"name": "writer", "delay": 0.06})
    writer.realtime = False  # a file backend: it gets every frame, late
    calls: list[tuple[int, int, list[str]]] = []
    result = Scheduler(
        neutral_frames(30),
        _open([writer], tmp_path, False),
        clock=MonotonicClock(),
        on_drain=lambda done, total, names: calls.append((done, total, names)),
    ).run()
    assert writer.indices == list(range(30)) and result.frames == 30
    assert len(calls) >= 2, "about four times a second while the writer catches up"
    assert all(names == ["writer"] for _, _, names in calls)
    totals = {total for _, total, _ in calls}
    assert len(totals) == 1 and totals.pop() >= 5
    done = [d for d, _, _ in calls]
    assert done == sorted(done) and done[-1] > done[0]


@needs_realtime
def test_a_paced_run_puts_the_producer_and_light_workers_just_below_the_clock(tmp_path: Path) -> None:
    """Measured: the clock waited 8-46 ms for the interpreter lock held by the producer or a worker
    that the OS had preempted. Those that work little a frame run real-time, below the clock."""
    import os

    from convodrive.plumbing.priority import CLOCK_FIFO_PRIORITY, HELPER_FIFO_PRIORITY

    seen: dict[str, set[tuple[int, int]]] = {"producer": set(), "light": set(), "heavy": set()}

    def policy() -> tuple[int, int]:
        return os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_getparam(0).sched_priority

    class Recorder(CountingBackend):
        light = False

        def send(self, frame):
            seen[self.name].add(policy())

    class LightRecorder(Recorder):
        light = True

    def source():
        for frame in neutral_frames(20):
            seen["producer"].add(policy())
            yield frame

    light, heavy = LightRecorder({"name": "light"}), Recorder({"name": "heavy"})
    result = Scheduler(source(), _open([light, heavy], tmp_path, False), clock=MonotonicClock()).run()
    assert result.clock_priority.startswith(f"SCHED_FIFO {CLOCK_FIFO_PRIORITY}")
    assert seen["producer"] == seen["light"] == {(os.SCHED_FIFO, HELPER_FIFO_PRIORITY)}
    assert HELPER_FIFO_PRIORITY < CLOCK_FIFO_PRIORITY
    assert {p for p, _ in seen["heavy"]} == {os.SCHED_OTHER}, "a backend that did not say it is light"


@needs_realtime
def test_a_thread_busier_than_it_promised_leaves_real_time_priority() -> None:
    """Its share is CPU time: a thread that waits (a live generator waiting for audio, a worker
    waiting for its child's answer) keeps real-time priority; one that computes for more than half
    a window leaves it."""
    import os
    import time

    from convodrive.plumbing.priority import HelperPriority

    def run() -> None:
        with HelperPriority(True, "generator") as helper:
            helper.WINDOW_S = 0.05
            assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
            for _ in range(3):  # waiting for all of three windows
                time.sleep(0.06)
                helper.tick()
            states.append((helper.active, os.sched_getscheduler(0)))
            time.sleep(0.06)
            helper.tick()
            spin_until = time.thread_time() + 0.05  # more than half the window: slower than real time
            while time.thread_time() < spin_until:
                pass
            helper.tick()
            states.append((helper.active, os.sched_getscheduler(0)))

    states: list[tuple[bool, int]] = []
    t = threading.Thread(target=run)
    t.start()
    t.join()
    assert states[0][0] and states[0][1] & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO, "waiting is not work"
    assert states[1] == (False, os.SCHED_OTHER)


@needs_realtime
def test_threads_a_helper_starts_share_its_priority_only_when_it_says_so() -> None:
    """A servo child's supervisor holds the bus its frames wait for: it shares the frames' priority
    (``inherit``); an ONNX Runtime pool that a generator starts does not."""
    import os

    from convodrive.plumbing.priority import HelperPriority

    def started_from(inherit: bool) -> int:
        policies: list[int] = []

        def helper() -> None:
            with HelperPriority(True, "helper", inherit=inherit):
                child = threading.Thread(target=lambda: policies.append(os.sched_getscheduler(0)))
                child.start()
                child.join()

        t = threading.Thread(target=helper)
        t.start()
        t.join()
        return policies[0] & ~os.SCHED_RESET_ON_FORK

    assert started_from(inherit=True) == os.SCHED_FIFO
    assert started_from(inherit=False) == os.SCHED_OTHER


def test_nothing_changes_priority_in_an_offline_run() -> None:
    import os

    from convodrive.plumbing.priority import HelperPriority

    before = os.sched_getscheduler(0)
    with HelperPriority(False, "generator") as helper:
        assert not helper.active and os.sched_getscheduler(0) == before


def test_a_frame_is_timed_to_when_it_left_not_to_when_send_returned(tmp_path: Path) -> None:
    """A backend may say when its frame left for the device (a child process answers after a round
    trip through a pipe): the dispatch-to-sent figure and ``on_sent`` end there."""
    lag = 0.03
    heard: list[float] = []

    class Answering(CountingBackend):
        def send(self, frame):
            super().send(frame)
            left = time.monotonic()
            time.sleep(lag)  # the way back, which is not the frame's latency
            return left

    backend = Answering({"name": "answering"})
    result = Scheduler(
        neutral_frames(20), _open([backend], tmp_path, False), clock=MonotonicClock(),
        on_sent=lambda name, frame, done: heard.append(time.monotonic() - done),
    ).run()  # fmt: skip
    figure = next(s for s in result.backends if s.name == "answering").dispatch_to_sent_ms.summary()
    assert figure is not None and figure["count"] >= 10
    assert figure["p50"] < 1000 * lag / 2, figure
    assert len(heard) == figure["count"] and min(heard) >= lag * 0.9, "on_sent gets the time the frame left"
