"""The feetech backend driving the emulated head through the real scservo_sdk over a pty, alone
and in whole runs (the pipeline and the ``convodrive drive`` command)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from tests.conftest import require, wait_for

pytestmark = require("hardware")

from convodrive.backends.base import Session  # noqa: E402
from convodrive.backends.feetech import FeetechBackend  # noqa: E402
from convodrive.backends.servo import feetech_packet as fp  # noqa: E402
from convodrive.backends.servo.emulator_faults import parse_fault  # noqa: E402
from convodrive.backends.servo.feetech_emulator import start_emulated_feetech  # noqa: E402
from convodrive.cli.drive import exit_code  # noqa: E402
from convodrive.motion.targets import TargetFrame  # noqa: E402
from convodrive.pipeline import DriveRequest, drive  # noqa: E402
from convodrive.retargeting import load_profile  # noqa: E402
from convodrive.samples import bundled_dialogue  # noqa: E402

PROFILE = load_profile("servo_head")
SPEC = PROFILE.spec
JOINTS = PROFILE.backend_options("feetech")["joints"]
LIMITS = {j["id"]: (j["min_tick"], j["max_tick"]) for j in JOINTS.values()}
FPS = 30


def options(port: str, **extra: object) -> dict:
    return {**PROFILE.backend_options("feetech"), "port": port, "ease_s": 0.3, "latency_ms": 40, **extra}


def test_frames_become_one_sync_write_each_and_close_eases_then_torque_off() -> None:
    n = 45
    t = np.arange(n)[:, None] / FPS
    half = (SPEC.upper - SPEC.lower) / 2
    frames = np.clip(
        SPEC.neutral + 0.6 * half * np.sin(2 * np.pi * 0.4 * t) * np.minimum(1.0, t), SPEC.lower, SPEC.upper
    )
    with start_emulated_feetech() as emu:
        backend = FeetechBackend(options(emu.port))
        backend.open(SPEC, Session(out_dir=Path("."), offline=False))
        first = len(emu.goal_log)
        start = time.monotonic()
        for i, values in enumerate(frames):
            backend.send(TargetFrame(i, i / FPS, values, ()))
            time.sleep(max(0.0, start + (i + 1) / FPS - time.monotonic()))
        backend.close()
        sent = emu.goal_log[first:]
        torque = [emu.servo(i).torque for i in range(1, 8)]
    report = backend.report()
    for k, name in enumerate(SPEC.names):
        j = JOINTS[name]
        per_unit = j.get("ticks_per_unit") or 4096 / (2 * np.pi)
        want = np.rint(j["zero_tick"] + j["direction"] * per_unit * frames[:, k])
        got = np.array([g.value for g in sent if g.servo_id == j["id"]][:n])
        assert got.shape == want.shape and np.max(np.abs(got - want)) <= 1, name
    per_frame = np.array([g.packet for g in sent[: 7 * n]]).reshape(n, 7)
    assert all(g.inst == fp.SYNC_WRITE for g in sent[: 7 * n]) and np.all(per_frame == per_frame[:, :1])
    assert report["status"] == "ok" and report["faults"] == [] and report["frames"] == n, report["faults"]
    assert report["eased_to_neutral"] and report["torque_off"] and not any(torque)
    assert report["servos"]["neck_pan"]["voltage_v"] == 12.0 and report["servos"]["jaw"]["temperature_c"] == 30


def test_every_injected_fault_is_named_and_the_run_completes(tmp_path: Path) -> None:
    """Faults injected at a frame of an offline run, which waits until the driver met each."""
    retries = 2
    with start_emulated_feetech() as emu:

        def inject(done: int, _total: int) -> None:
            if done == 30:
                seen = emu.counters["replies"]
                emu.hardware_error(4, "overload")
                emu.hardware_error(2, "overheating")
                emu.hardware_error(3, "input_voltage")
                emu.vanish(6)
                emu.drop_replies(2, servo_id=1)
                emu.corrupt_replies(2, servo_id=5)
                emu.short_replies(2, servo_id=7)
                wait_for(lambda: emu.unanswered[6] >= 2 + retries, "the driver to give up on servo 6", timeout=60.0)
                wait_for(lambda: emu.counters["replies"] > seen + 14, "two more health reads", timeout=60.0)
                wait_for(
                    lambda: emu.counters["shortened"] >= 2 and emu.counters["corrupted"] >= 2,
                    "the bad replies",
                    timeout=60.0,
                )
            elif done == 120:
                emu.reappear(6)

        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("feetech",),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"feetech": options(emu.port, read_rate=20, retries=retries, latency_ms=16)},
        )
        result = drive(request, on_frame=inject)
        torque = [emu.servo(i).torque for i in range(1, 8)]
    entry = result.report["backends"]["feetech"]
    assert result.report["frames"] == result.report["expected_frames"] and not entry["failed"]
    report = entry["report"]
    want = {
        "overload:jaw",
        "overheating:neck_tilt",
        "input_voltage:neck_roll",
        "servo_lost:eye_tilt",
        "lost_replies:neck_pan",
        "bad_checksum:eye_pan",
        "short_replies:eyelids",
    }
    assert want <= set(report["faults"]), report["faults"]
    assert any(e["event"] == "servo_recovered" for e in report["events"])
    assert report["status"] == "degraded" and report["torque_off"] and not any(torque)
    assert exit_code(result) == 0


def test_the_only_servo_head_failing_exits_3(tmp_path: Path) -> None:
    """Servo 6 is gone for the whole run: its torque-off cannot be confirmed, so the head fails."""
    with start_emulated_feetech(faults=[parse_fault("vanish:6@0+600")]) as emu:
        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("feetech",),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"feetech": options(emu.port, ease_s=0.2)},
        )
        result = drive(request)
    assert "feetech" in result.report["hardware_failed"]
    assert "torque off not confirmed for eye_tilt" in result.report["hardware_failed"]["feetech"]
    assert exit_code(result) == 3


@pytest.mark.slow
def test_convodrive_drive_at_30_hz_keeps_every_goal_inside_the_limits(tmp_path: Path) -> None:
    """The command a user runs against ``convodrive emulate feetech``, in real time, on the bundled
    dialogue's first 10 s (a talking turn, a listening one and the pauses between)."""
    data, rate = sf.read(str(bundled_dialogue()), dtype="float32")
    excerpt = tmp_path / "dialogue_10s.wav"
    sf.write(excerpt, data[: 10 * rate], rate)
    with start_emulated_feetech() as emu:
        out = subprocess.run(
            [sys.executable, "-m", "convodrive.cli.main", "drive", str(excerpt),
             "--backend", "feetech", "--out", str(tmp_path / "o"), "-B", f"feetech.port={emu.port}"],
            capture_output=True, text=True, timeout=240,
        )  # fmt: skip
        goals = list(emu.goal_log)
        torque = [emu.servo(i).torque for i in range(1, 8)]
    assert out.returncode == 0, out.stderr
    report = json.loads((tmp_path / "o" / "run_report.json").read_text())
    head = report["backends"]["feetech"]["report"]
    assert report["frames"] == report["expected_frames"] >= 10 * FPS and abs(report["effective_fps"] - FPS) < 0.5
    outside = [g for g in goals if not LIMITS[g.servo_id][0] <= g.value <= LIMITS[g.servo_id][1]]
    assert len(goals) >= 7 * report["frames"] and outside == []
    assert head["torque_off"] is True and not any(torque) and head["goal_writes"] >= report["frames"]


def test_calibration_is_written_in_the_dynamixel_heads_format(tmp_path: Path) -> None:
    from convodrive.cli.servo import set_joint_limits

    source = Path(PROFILE.path)
    target = tmp_path / "head.yaml"
    target.write_text(set_joint_limits(source.read_text(), "feetech", {"jaw": (1800, 2050)}, source))
    calibrated = load_profile(str(target))
    assert (calibrated.backend_options("feetech")["joints"]["jaw"]["min_tick"], 2050) == (1800, 2050)
    assert calibrated.backend_options("dynamixel")["joints"]["jaw"]["min_tick"] == 1819, "the other bus untouched"
    backend = FeetechBackend({**calibrated.backend_options("feetech"), "port": "/dev/null"})
    backend._hw_calibration(calibrated.spec)
    assert backend._limits["jaw"] == (1800, 2050)
