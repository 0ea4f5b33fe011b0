"""Logging: events on stderr as they happen (warnings by default, -v more, -q errors only), the same
and more in ``--log-file``; the one-line user errors stay as they are."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest

from convodrive.backends.base import Backend
from convodrive.motion.bvh import write_bvh
from convodrive.motion.clip import MotionClip
from convodrive.motion.targets import TargetFrame
from convodrive.scheduler import Route, Scheduler, SimulatedClock
from tests.conftest import run_cli
from tests.doubles import CountingBackend, neutral_frames


@pytest.fixture
def faceless_bvh(tmp_path: Path) -> Path:
    clip = MotionClip.neutral(30)
    clip.pose[:, 15, 1] = 0.2
    return write_bvh(clip, tmp_path / "nod.bvh")


def test_warnings_show_by_default_and_quiet_hides_them(tone_dialogue: Path, faceless_bvh: Path, tmp_path: Path) -> None:
    args = ["drive", str(tone_dialogue), "--generator", "replay", "--motion", str(faceless_bvh)]
    loud = run_cli(*args, "--out", str(tmp_path / "a"))
    assert loud.returncode == 0, loud.stderr
    lines = loud.stderr.strip().splitlines()
    assert f"convodrive: warning: replay: {faceless_bvh}: plays no face (every blendshape channel is 0)" in lines
    assert (
        f"convodrive: warning: replay: {faceless_bvh}: the clip lasts 1.00 s but the audio 3.00 s: its last frame is held for 2.00 s"
        in lines
    )
    assert "convodrive: info:" not in loud.stderr, "progress only with -v"
    quiet = run_cli(*args, "--out", str(tmp_path / "b"), "-q")
    assert quiet.returncode == 0 and quiet.stderr == ""
    verbose = run_cli("-v", *args, "--out", str(tmp_path / "c"))  # -v before the subcommand works too
    assert "convodrive: info: record: open" in verbose.stderr.splitlines()


def test_log_file_keeps_events_errors_and_the_summary(tone_dialogue: Path, faceless_bvh: Path, tmp_path: Path) -> None:
    log_file = tmp_path / "logs" / "run.log"
    out = run_cli(
        "drive", str(tone_dialogue), "--generator", "replay", "--motion", str(faceless_bvh),
        "--out", str(tmp_path / "o"), "--log-file", str(log_file), "-q",
    )  # fmt: skip
    assert out.returncode == 0 and out.stderr == ""
    text = log_file.read_text()
    assert " INFO    convodrive.pipeline.backends: record: open" in text
    assert " WARNING convodrive.generators.replay: replay: " in text and "plays no face" in text
    assert "run summary" in text and "offline run: 90 frames" in text
    failed = run_cli("drive", str(tmp_path / "absent.wav"), "--log-file", str(log_file))
    assert failed.returncode == 2 and failed.stderr.count("\n") == 1, "the one-line error stays one line"
    assert f" ERROR   convodrive.cli: {tmp_path / 'absent.wav'}: no such file" in log_file.read_text()


def test_an_unwritable_log_file_is_one_line(tone_dialogue: Path) -> None:
    out = run_cli("drive", str(tone_dialogue), "--log-file", "/sys/convodrive.log")
    assert out.returncode == 2 and out.stderr.strip() == (
        "convodrive: error: --log-file /sys/convodrive.log: cannot write (permission denied)"
    )


class _FailsFrom(Backend):
    """Works for ``good`` frames, then raises on every frame, like a servo head whose port vanished."""

    name = "flaky"

    def __init__(self, good: int) -> None:
        super().__init__()
        self.good = good

    def send(self, frame: TargetFrame) -> None:
        if frame.index >= self.good:
            raise OSError("port vanished")


def test_a_backend_fault_is_logged_while_the_run_goes_on(caplog: pytest.LogCaptureFixture) -> None:
    observer = CountingBackend({"name": "observer"})
    seen_at: list[int] = []

    class Spy(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if "port vanished" in record.getMessage():
                seen_at.append(len(observer.indices))

    spy = Spy()
    logging.getLogger("convodrive").addHandler(spy)
    try:
        routes: list[Any] = [Route(_FailsFrom(good=20), None), Route(observer, None)]
        result = Scheduler(neutral_frames(300), routes, clock=SimulatedClock()).run()
    finally:
        logging.getLogger("convodrive").removeHandler(spy)
    assert result.frames == 300 and len(observer.indices) == 300
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert "flaky: frame 20: OSError: port vanished" in warnings
    assert seen_at and seen_at[0] < 100, "logged when it happened, not after the run"
    assert any(
        r.levelname == "ERROR" and r.getMessage().startswith("flaky: failed after frame 109: ") for r in caplog.records
    )
