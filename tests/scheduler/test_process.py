"""A backend in a process of its own: frames, errors, reports and outputs cross the pipe, and the
child dying, stalling or being stopped is a failure of that backend alone."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from convodrive.backends.base import BackendFailed, Session
from convodrive.plumbing.errors import UserError
from convodrive.scheduler import MonotonicClock, Route, Scheduler, SimulatedClock
from convodrive.scheduler.process import ProcessBackend
from convodrive.scheduler.report import build_report
from tests.doubles import ChildProbeBackend, CountingBackend, neutral_frames


def _opened(backends: list, tmp_path: Path, offline: bool) -> list[Route]:
    for b in backends:
        b.open(b.spec, Session(out_dir=tmp_path, offline=offline))
    return [Route(b) for b in backends]


def test_frames_report_health_and_outputs_cross_the_pipe(tmp_path: Path) -> None:
    child = ProcessBackend(ChildProbeBackend({"name": "probe"}))
    here = CountingBackend({"name": "here"})
    result = Scheduler(neutral_frames(60), _opened([child, here], tmp_path, True), clock=SimulatedClock()).run()

    report = build_report(result, {})["backends"]["probe"]
    assert report["report"]["indices"] == list(range(60)), "every frame, in order, reached the child"
    assert report["report"]["closed"] is True
    assert report["report"]["pid"] != os.getpid(), "the backend ran in another process"
    assert report["report"]["process"]["exit"] == "exit code 0"
    assert report["health"]["status"] == "ok" and report["health"]["frames"] == 60
    assert report["frames_sent"] == 60 and report["errors"] == 0 and not report["failed"]
    assert child.outputs() == [tmp_path / "probe_indices.txt"]
    assert (tmp_path / "probe_indices.txt").read_text().split() == [str(i) for i in range(60)]
    assert here.indices == list(range(60))


def test_errors_in_the_child_read_as_they_were_raised(tmp_path: Path) -> None:
    child = ProcessBackend(ChildProbeBackend({"name": "probe", "fail_at": 3, "close_error": "disk full"}))
    result = Scheduler(neutral_frames(10), _opened([child], tmp_path, True), clock=SimulatedClock()).run()
    stats = result.backends[0]
    assert stats.errors == 1 and stats.last_error == "OSError: port vanished"
    assert stats.sent == 9 and not stats.failed
    assert stats.close_error == "RuntimeError: disk full"
    assert result.backend_reports["probe"]["indices"] == [0, 1, 2, 4, 5, 6, 7, 8, 9]
    assert (tmp_path / "probe_indices.txt").is_file(), "outputs are finished before the close error"


def test_a_user_error_at_open_stays_a_user_error() -> None:
    backend = ProcessBackend(
        ChildProbeBackend({"name": "probe", "open_user_error": "backends.probe.port: no such port"})
    )
    with pytest.raises(UserError, match=r"^backends\.probe\.port: no such port$"):
        backend.open(backend.spec, Session(out_dir=Path("."), offline=False))
    assert backend._process is not None and backend._process.poll() is not None, "the child is gone"


def test_a_child_that_dies_fails_its_backend_and_the_run_goes_on(tmp_path: Path) -> None:
    dying = ProcessBackend(ChildProbeBackend({"name": "dying", "die_at": 20}))
    here = CountingBackend({"name": "here"})
    frames = 45
    result = Scheduler(neutral_frames(frames), _opened([dying, here], tmp_path, False), clock=MonotonicClock()).run()

    assert result.frames == frames and here.indices == list(range(frames))
    report = build_report(result, {})["backends"]["dying"]
    assert report["failed"] and report["errors"] == 1, "a dead process fails at once, without 90 retries"
    assert report["last_error"] == "BackendFailed: its process died (killed by SIGKILL)"
    assert report["frames_sent"] == 20 and report["frames_dropped"] == frames - 21  # frame 20 was the error
    assert report["health"]["status"] == "failed" and "SIGKILL" in report["health"]["reason"]
    assert "SIGKILL" in report["report"]["error"] and "SIGKILL" in report["close_error"]
    with pytest.raises(BackendFailed):
        dying.send(None)  # type: ignore[arg-type]


def test_sigterm_to_the_child_finishes_its_outputs(tmp_path: Path) -> None:
    backend = ProcessBackend(ChildProbeBackend({"name": "probe"}))
    backend.open(backend.spec, Session(out_dir=tmp_path, offline=False))
    from convodrive.motion.targets import TargetFrame

    frame = next(neutral_frames(1))
    for i in range(5):
        backend.send(TargetFrame(i, i / 30, ChildProbeBackend({}).spec.lower, frame))
    assert backend._process is not None
    backend._process.send_signal(signal.SIGTERM)
    backend._process.wait(timeout=30)
    with pytest.raises(BackendFailed, match="SIGTERM"):
        backend.send(TargetFrame(5, 5 / 30, ChildProbeBackend({}).spec.lower, frame))
    backend.close()
    assert backend.report()["indices"] == [0, 1, 2, 3, 4]
    assert (tmp_path / "probe_indices.txt").read_text() == "0 1 2 3 4"


def test_hurry_reaches_the_child(tmp_path: Path) -> None:
    flag = tmp_path / "hurried"
    backend = ProcessBackend(ChildProbeBackend({"name": "probe", "hurry_file": str(flag)}))
    backend.open(backend.spec, Session(out_dir=tmp_path, offline=False))
    backend.hurry()
    deadline = time.monotonic() + 10
    while not flag.exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    backend.close()
    assert flag.read_text() == "hurried"


def test_a_second_stop_drops_the_backlog_and_hurries_every_backend(tmp_path: Path) -> None:
    """Stop once: file backends still get the frames already made. Stop again: at once.

    Both stops follow the run's own progress, not wall time: under a loaded CI machine the clock
    may start late, and a timer would stop a run that had barely begun."""
    flag = tmp_path / "hurried"
    slow = ChildProbeBackend({"name": "slow", "delay": 0.1, "hurry_file": str(flag)})
    slow.realtime = False  # a file backend: a backlog, not a latest-value slot
    stop_at = 30
    sent_at_stop: list[int] = []

    def hurry_once_the_backlog_moves() -> None:
        deadline = time.monotonic() + 60
        while len(slow.indices) < sent_at_stop[0] + 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        scheduler.hurry()

    def stop_at_frame(index: int) -> None:
        if index == stop_at - 1:
            sent_at_stop.append(len(slow.indices))
            scheduler.request_stop()
            threading.Thread(target=hurry_once_the_backlog_moves, daemon=True).start()

    scheduler = Scheduler(
        neutral_frames(10_000), _opened([slow], tmp_path, False), clock=MonotonicClock(), on_frame=stop_at_frame
    )
    result = scheduler.run()
    assert result.interrupted and flag.exists()
    stats = result.backends[0]
    assert result.frames == stop_at, "the first stop ends the clock at the next frame boundary"
    assert sent_at_stop[0] < stop_at - 3, "a backlog was waiting when the run stopped"
    assert stats.sent >= sent_at_stop[0] + 3, "after the first stop, the backlog kept going out"
    assert stats.dropped > 0 and stats.sent + stats.dropped == result.frames
    assert slow.indices == list(range(stats.sent))
