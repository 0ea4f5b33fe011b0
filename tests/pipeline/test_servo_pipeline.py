"""End to end: the bundled dialogue, retargeted onto the servo head, reaches the emulated servos."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.backends.servo import dynamixel_packet as dp
from convodrive.backends.servo.dynamixel_emulator import start_emulated_head
from convodrive.backends.servo.emulator_faults import parse_fault
from convodrive.motion.npz import load_clip
from convodrive.pipeline import DriveRequest, drive
from convodrive.retargeting import Retargeter, load_profile
from convodrive.samples import bundled_dialogue
from tests.conftest import wait_for

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
    """Faults are injected at a frame of the run, and the run is held (an offline clock waits)
    until the driver has met each, so a loaded machine cannot move them outside the run."""
    retries = 2
    with start_emulated_head(faults=[parse_fault("corrupt:0.02")]) as emu:

        def inject(done: int, _total: int) -> None:
            if done == 30:  # a second into the run: the head is open and moving
                status_reads = emu.requests[(4, dp.READ)]
                emu.hardware_error(4, "overload")
                emu.vanish(6)
                wait_for(
                    lambda: emu.requests[(4, dp.READ)] > status_reads,
                    "the driver to read servo 4's error",
                    timeout=60.0,
                )
                # One group read, then the servo alone, 1 + retries times: after that it is lost.
                wait_for(lambda: emu.unanswered[6] >= 2 + retries, "the driver to give up on servo 6", timeout=60.0)
            elif done == 90:
                emu.reappear(6)

        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("dynamixel",),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"dynamixel": {"port": emu.port, "ease_s": 0.2, "read_rate": 20, "retries": retries}},
        )
        result = drive(request, on_frame=inject)
        torque = [emu.servo(i).torque for i in range(1, 8)]
    entry = result.report["backends"]["dynamixel"]
    assert result.report["frames"] == result.report["expected_frames"] and not entry["failed"]
    assert entry["frames_sent"] == result.report["frames"]
    report = entry["report"]
    assert {"overload:jaw", "servo_lost:eye_tilt"} <= set(report["faults"]), report["faults"]
    assert report["status"] == "degraded" and report["torque_off"] and not any(torque)
    assert "degraded" in {e["status"] for e in entry["health_events"]}


def test_short_replies_degrade_the_head_and_the_run_goes_on(tmp_path: Path) -> None:
    """Status packets with too little data (the SDK raised IndexError on them, or read their
    checksum as data) are one servo's bad exchanges: counted, retried, named; never the run's end."""
    with start_emulated_head() as emu:

        def inject(done: int, _total: int) -> None:
            if done == 30:
                emu.short_replies(3, servo_id=2)
                wait_for(lambda: emu.counters["shortened"] >= 3, "the driver to read servo 2 three times", timeout=60.0)

        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("record", "dynamixel"),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"dynamixel": {"port": emu.port, "ease_s": 0.2, "read_rate": 20}},
        )
        result = drive(request, on_frame=inject)
        torque = [emu.servo(i).torque for i in range(1, 8)]
    entry = result.report["backends"]["dynamixel"]
    assert result.report["frames"] == result.report["expected_frames"]
    assert entry["frames_sent"] == result.report["frames"] and not entry["failed"] and not entry["errors"]
    report = entry["report"]
    assert "short_replies:neck_tilt" in report["faults"], report["faults"]
    assert report["servos"]["neck_tilt"]["short"] >= 1
    assert not any(f.startswith("poll_error") for f in report["faults"]), report["faults"]
    assert report["status"] == "degraded" and report["torque_off"] and not any(torque)
    assert result.report["backends"]["record"]["frames_sent"] == result.report["frames"]


def test_the_summary_names_the_lost_servo(tmp_path: Path) -> None:
    """Servo 6 goes at the run's first frame and never comes back: the head fails (its torque-off
    cannot be confirmed), and the summary line says which servo and why. (Gone before the run, it
    is refused at open.)"""
    with start_emulated_head() as emu:

        def vanish(done: int, _total: int) -> None:
            if done == 1:
                emu.vanish(6)

        request = DriveRequest(
            audio=bundled_dialogue(),
            backends=("dynamixel",),
            out_dir=tmp_path,
            realtime=False,
            backend_options={"dynamixel": {"port": emu.port, "ease_s": 0.2}},
        )
        result = drive(request, on_frame=vanish)
    line = next(line for line in result.summary_path.read_text().splitlines() if "dynamixel" in line)
    assert "FAILED" in line and "torque off not confirmed for eye_tilt" in line, line
    assert "servo lost (eye_tilt)" in line, line
    assert result.report["hardware_failed"] == {"dynamixel": line[line.index("(") + 1 : -1]}


def test_a_profile_borne_option_error_names_the_profile(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Defect 16 (issue 31): a joint the profile's own ``backends.dynamixel.joints`` misspells is
    found only at open; the one-line error must name the profile file it came from."""
    from convodrive.cli.main import main
    from convodrive.retargeting.profile import resolve_profile_path

    text = Path(resolve_profile_path("servo_head")).read_text(encoding="utf-8")
    assert text.count("      neck_pan:  {id: 1,") == 2  # the dynamixel and the feetech entry
    profile = tmp_path / "my_head.yaml"
    profile.write_text(text.replace("      neck_pan:  {id: 1,", "      neck_pann:  {id: 1,", 1), encoding="utf-8")
    args = ["drive", str(bundled_dialogue()), "--backend", "dynamixel", "--config", str(profile)]
    code = main([*args, "-B", "dynamixel.port=/dev/null", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert str(profile) in err[0] and "backends.dynamixel.joints: neck_pann not in profile" in err[0], err
    # Set on the command line instead, the same mistake names no file.
    code = main(
        [*args[:-2], "-B", "dynamixel.port=/dev/null", "-B", "dynamixel.joints.nope.id=9", "--out", str(tmp_path / "o")]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and str(profile) not in err[0], err
