"""How a servo head ends a run: eased to neutral within a bounded time, checked by reading the
servos back, torque off; at once when the user insists; and a run whose hardware failed says so."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from convodrive.backends.dynamixel import HEALTH_REGISTERS, DynamixelBackend
from convodrive.backends.servo import servo_base
from convodrive.backends.servo.dynamixel_emulator import start_emulated_head
from tests.backends.servo.test_dynamixel_backend import SPEC, drive, expected_ticks, options, session, trajectory
from tests.doubles import CountingBackend


def _away() -> np.ndarray:
    return np.clip(SPEC.neutral + 0.3, SPEC.lower, SPEC.upper)


def _last_goals(emu, since: int) -> dict[int, int]:
    return {g.servo_id: g.tick for g in emu.goal_log[since:]}


@pytest.mark.parametrize(
    ("value", "problem"), [("1e9", "between 0.1 and 10"), ("-5", "between 0.1 and 10"), (".nan", "a finite number")]
)
def test_a_servo_timing_outside_its_range_is_refused_before_anything_moves(
    value: str, problem: str, tmp_path: Path
) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "convodrive.cli.main", "drive", str(_tone(tmp_path / "t.wav", 1.0)),
         "--backend", "dynamixel", "--out", str(tmp_path / "o"), "-B", "dynamixel.port=/dev/null",
         "-B", f"dynamixel.ease_s={value}"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    assert "ease_s" in out.stderr and problem in out.stderr


def test_the_ease_has_a_hard_cap_whatever_the_options_say(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(servo_base, "MAX_EASE_S", 0.6)  # the real cap is 10 s: too long for a test
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port, ease_s=10.0))
        backend.open(SPEC, session())
        drive(backend, np.linspace(SPEC.neutral, _away(), 10))
        before = len(emu.goal_log)
        t0 = time.monotonic()
        backend.close()
        took = time.monotonic() - t0
        last = _last_goals(emu, before)
    assert took < 0.6 + servo_base.NEUTRAL_SETTLE_S + 1.5, took
    assert last == expected_ticks(SPEC.neutral)
    assert backend.report()["torque_off"] is True


def test_hurry_during_the_ease_cuts_torque_at_once() -> None:
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port, ease_s=8.0))
        backend.open(SPEC, session())
        drive(backend, np.linspace(SPEC.neutral, _away(), 10))
        threading.Timer(0.3, backend.hurry).start()
        t0 = time.monotonic()
        backend.close()
        took = time.monotonic() - t0
        torque = [emu.servo(i).torque for i in range(1, 8)]
    report = backend.report()
    assert took < 1.5, f"the second Ctrl-C must not wait for an 8 s ease ({took:.2f} s)"
    assert not any(torque) and report["torque_off"] is True
    assert report["eased_to_neutral"] is False
    assert any(e["event"] == "hurried" for e in report["events"])


def test_eased_to_neutral_is_what_the_servos_read_back() -> None:
    """An overloaded servo switches itself off and stays where it is: the ease cannot move it."""
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port))
        backend.open(SPEC, session())
        drive(backend, np.linspace(SPEC.neutral, _away(), 20))
        time.sleep(0.3)  # let the head arrive where it was sent
        emu.hardware_error(4, "overload")  # servo 4 drives the jaw
        stuck_at = emu.servo(4).present
        backend.close()
        neutral = expected_ticks(SPEC.neutral)
    report = backend.report()
    assert abs(stuck_at - neutral[4]) > 2 * backend.neutral_tolerance_raw, "the jaw was away from neutral"
    assert report["eased_to_neutral"] is False
    assert report["neutral_error_raw"]["jaw"] == pytest.approx(abs(stuck_at - neutral[4]), abs=2)
    assert all(e <= backend.neutral_tolerance_raw for n, e in report["neutral_error_raw"].items() if n != "jaw")
    assert "not_at_neutral:jaw" in report["faults"] and report["status"] == "degraded"
    assert "not at neutral (jaw)" in report["reason"]


def test_a_normal_close_reads_every_servo_at_neutral() -> None:
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port))
        backend.open(SPEC, session())
        drive(backend, trajectory(20))
        backend.close()
    report = backend.report()
    assert report["eased_to_neutral"] is True
    assert set(report["neutral_error_raw"]) == set(SPEC.names)
    assert max(report["neutral_error_raw"].values()) <= backend.neutral_tolerance_raw


def test_one_timed_out_group_read_charges_no_servo_that_answers_alone() -> None:
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port, read_rate=0.5))  # few background reads
        backend.open(SPEC, session())
        bus = backend.bus
        assert bus is not None
        emu.drop_replies(7)  # the whole SYNC_READ goes unanswered, once
        data = bus.sync_read(HEALTH_REGISTERS)
        timeouts = {n: h.timeouts for n, h in bus.health.items()}
        backend.close()
    assert set(data) == set(SPEC.names), "each servo answered when asked alone"
    assert timeouts == dict.fromkeys(SPEC.names, 0), timeouts
    assert bus.group_timeouts == 1
    assert not [f for f in backend.report()["faults"] if f.startswith("lost_replies")]


# ---------------------------------------------------------------------- through the CLI
def _tone(path: Path, seconds: float) -> Path:
    import soundfile as sf

    sr = 16_000
    t = np.arange(int(sr * seconds)) / sr
    sf.write(path, np.stack([0.3 * np.sin(2 * np.pi * 150 * t)] * 2, axis=1).astype(np.float32), sr)
    return path


def _start_drive(tmp_path: Path, port: str, *extra: str) -> subprocess.Popen[str]:
    audio = _tone(tmp_path / "tone.wav", 20.0)
    args = ["drive", str(audio), "--backend", "record,dynamixel", "--out", str(tmp_path / "o")]
    args += ["-B", f"dynamixel.port={port}", "-B", "dynamixel.latency_ms=40", *extra]
    proc = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a shell gives a foreground job
    )
    assert proc.stderr is not None
    # The run says it is live once its clock starts; on a loaded machine a warning (a status read
    # that timed out) may come first, so read past those, but not past the end of its output.
    seen = [proc.stderr.readline()]
    while seen[-1] and "real time" not in seen[-1] and len(seen) < 20:
        seen.append(proc.stderr.readline())
    assert "real time" in seen[-1], seen
    return proc


def test_a_second_ctrl_c_during_the_ease_cuts_torque_at_once(tmp_path: Path) -> None:
    with start_emulated_head() as emu:
        proc = _start_drive(tmp_path, emu.port, "-B", "dynamixel.ease_s=8")
        time.sleep(1.5)
        os.killpg(proc.pid, signal.SIGINT)  # stop: the head starts an 8 s ease to neutral
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGINT)  # again: cut torque now
        t0 = time.monotonic()
        _, stderr = proc.communicate(timeout=60)
        took = time.monotonic() - t0
        torque = [emu.servo(i).torque for i in range(1, 8)]
    assert proc.returncode == 130, stderr
    assert took < 4.0, f"the run went on for {took:.1f} s after the second Ctrl-C"
    assert not any(torque)
    report = json.loads((tmp_path / "o" / "run_report.json").read_text())
    head = report["backends"]["dynamixel"]["report"]
    assert head["torque_off"] is True and head["eased_to_neutral"] is False
    assert any(e["event"] == "hurried" for e in head["events"])


def test_torque_off_unconfirmed_exits_non_zero_and_says_so(tmp_path: Path) -> None:
    with start_emulated_head() as emu:
        proc = _start_drive(tmp_path, emu.port, "-B", "dynamixel.ease_s=0.2")
        time.sleep(1.0)
        emu.unplug()  # the adapter is gone for good: torque off cannot be confirmed
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 3, stderr
    last = stderr.strip().splitlines()[-1]
    assert last.startswith("convodrive: hardware failed (dynamixel: torque off not confirmed"), last
    report = json.loads((tmp_path / "o" / "run_report.json").read_text())
    assert "dynamixel" in report["hardware_failed"]


class BrokenHead(CountingBackend):
    """A servo head whose adapter fails as it opens (not the user's mistake: the hardware's)."""

    hardware = True

    def open(self, spec, session) -> None:
        raise OSError("USB adapter stopped answering")


def test_the_only_servo_head_failing_at_open_fails_the_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from convodrive.cli.drive import exit_code, print_result
    from convodrive.pipeline import DriveRequest, drive
    from convodrive.pipeline import backends as planning

    monkeypatch.setattr(planning, "load_plugin", lambda group, name: BrokenHead)
    result = drive(DriveRequest(audio=_tone(tmp_path / "t.wav", 1.0), backends=("fast",), out_dir=tmp_path / "o"))
    assert result.report["hardware_failed"] == {"fast": "OSError: USB adapter stopped answering"}
    print_result(result)
    assert exit_code(result) == 3
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last == "convodrive: hardware failed (fast: OSError: USB adapter stopped answering); exit code 3"


def test_a_bad_servo_option_exits_non_zero_in_one_line(tmp_path: Path) -> None:
    with start_emulated_head() as emu:
        out = subprocess.run(
            [sys.executable, "-m", "convodrive.cli.main", "drive", str(_tone(tmp_path / "t.wav", 1.0)),
             "--backend", "dynamixel", "--out", str(tmp_path / "o"),
             "-B", f"dynamixel.port={emu.port}", "-B", "dynamixel.baudrate=fast"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
    assert out.returncode != 0, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert "dynamixel" in last and "Traceback" not in out.stderr, out.stderr
