"""End to end: the bundled dialogue, retargeted onto the servo head, reaches the emulated servos."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.backends.servo import dynamixel_packet as dp
from convodrive.backends.servo.dynamixel_emulator import parse_fault, start_emulated_head
from convodrive.motion.npz import load_clip
from convodrive.pipeline import DriveRequest, drive
from convodrive.retargeting import Retargeter, load_profile
from convodrive.samples import bundled_dialogue

pytestmark = [pytest.mark.hardware]


def test_dialogue_goal_log_matches_the_retargeted_trajectory(tmp_path: Path) -> None:
    profile = load_profile("servo_head")
    with start_emulated_head() as emu:
        # A long watchdog: on a busy machine an offline run may pause, and an ease would
        # interleave extra goals; the watchdog itself is tested elsewhere.
        # Offline (simulated clock) so that every frame reaches the head and the comparison is exact;
        # the real-time run is the demo's, checked in test_demo.py.
        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("record", "dynamixel"),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"dynamixel": {"port": emu.port, "ease_s": 0.2, "watchdog_s": 5.0, "latency_ms": 40}},
        )
        result = drive(request)
        goals = {i: [g.tick for g in emu.goals(i, dp.SYNC_WRITE)] for i in range(1, 8)}
        torque = [emu.servo(i).torque for i in range(1, 8)]
    clip_path = next(p for p in result.outputs if p.suffix == ".npz" and "targets" not in p.name)
    values = Retargeter(profile).retarget_clip(load_clip(clip_path))
    joints = profile.backend_options("dynamixel")["joints"]
    assert len(values) > 300 and np.ptp(values[:, 0]) > 0.05  # the head really moved
    for k, name in enumerate(profile.spec.names):
        j = joints[name]
        per_unit = j.get("ticks_per_unit") or 4096 / (2 * np.pi)
        want = np.rint(j["zero_tick"] + j["direction"] * per_unit * values[:, k])
        got = np.array(goals[j["id"]][: len(values)])
        assert got.shape == want.shape, name
        assert np.max(np.abs(got - want)) <= 1, name
    assert not any(torque)
    assert result.report["backends"]["dynamixel"]["health"]["status"] == "ok"


def test_faults_during_a_run_are_named_in_the_run_report(tmp_path: Path) -> None:
    faults = [parse_fault("overload:4@0.3"), parse_fault("vanish:6@0.3+0.5"), parse_fault("corrupt:0.02")]
    with start_emulated_head(faults=faults) as emu:
        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("dynamixel",),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"dynamixel": {"port": emu.port, "ease_s": 0.2, "read_rate": 20}},
        )
        result = drive(request)
        torque = [emu.servo(i).torque for i in range(1, 8)]
    entry = result.report["backends"]["dynamixel"]
    assert result.report["frames"] == result.report["expected_frames"] and not entry["failed"]
    assert entry["frames_sent"] == result.report["frames"]
    report = entry["report"]
    assert {"overload:jaw", "servo_lost:eye_tilt"} <= set(report["faults"]), report["faults"]
    assert report["status"] == "degraded" and report["torque_off"] and not any(torque)
    assert "degraded" in {e["status"] for e in entry["health_events"]}


def test_the_summary_names_the_lost_servo(tmp_path: Path) -> None:
    """Servo 6 is gone for the whole run: the head fails (its torque-off cannot be confirmed), and
    the summary line says which servo and why."""
    with start_emulated_head(faults=[parse_fault("vanish:6@0+600")]) as emu:
        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("dynamixel",),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"dynamixel": {"port": emu.port, "ease_s": 0.2}},
        )
        result = drive(request)
    line = next(line for line in result.summary_path.read_text().splitlines() if "dynamixel" in line)
    assert "FAILED" in line and "torque off not confirmed for eye_tilt" in line, line
    assert "servo lost (eye_tilt)" in line, line
    assert result.report["hardware_failed"] == {"dynamixel": line[line.index("(") + 1 : -1]}
