"""The dynamixel backend driving the emulated head through the real dynamixel_sdk over a pty."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest

from convodrive.backends.base import Session
from tests.conftest import needs_realtime, require, wait_for

pytestmark = require("hardware")

from convodrive.backends.dynamixel import DynamixelBackend  # noqa: E402
from convodrive.backends.servo import dynamixel_packet as dp  # noqa: E402
from convodrive.backends.servo.dynamixel_emulator import DynamixelEmulator, start_emulated_head  # noqa: E402
from convodrive.motion.targets import TargetFrame  # noqa: E402
from convodrive.plumbing.errors import UserError  # noqa: E402
from convodrive.retargeting import load_profile  # noqa: E402

PROFILE = load_profile("servo_head")
SPEC = PROFILE.spec
FPS = 30


def options(port: str, **extra: object) -> dict:
    opts = PROFILE.backend_options("dynamixel")
    # 40 ms latency budget: this machine is shared and busy; fault tests use the SDK's 16 ms.
    opts.update({"port": port, "ease_s": 0.3, "read_rate": 20, "latency_ms": 40, **extra})
    return opts


def expected_ticks(values: np.ndarray) -> dict[int, int]:
    """Ticks from the profile's calibration, computed independently of the backend."""
    out = {}
    for name, v in zip(SPEC.names, values):
        j = PROFILE.backend_options("dynamixel")["joints"][name]
        per_unit = j.get("ticks_per_unit") or 4096 / (2 * np.pi)
        out[j["id"]] = int(round(j["zero_tick"] + j["direction"] * per_unit * v))
    return out


def trajectory(n: int) -> np.ndarray:
    """A smooth in-limits trajectory (as the retargeter would hand over), starting at neutral."""
    t = np.arange(n)[:, None] / FPS
    mid, half = (SPEC.lower + SPEC.upper) / 2, (SPEC.upper - SPEC.lower) / 2
    wave = np.sin(2 * np.pi * 0.4 * t + np.arange(len(SPEC.names))) * np.minimum(1.0, t)
    return np.clip(SPEC.neutral + 0.6 * half * wave + 0 * mid, SPEC.lower, SPEC.upper)


def drive(backend: DynamixelBackend, frames: np.ndarray, during=None) -> None:
    """Send frames on a 30 fps wall clock; ``during(i)`` may inject a fault."""
    start = time.monotonic()
    for i, values in enumerate(frames):
        if during is not None:
            during(i)
        backend.send(TargetFrame(i, i / FPS, values, ()))
        time.sleep(max(0.0, start + (i + 1) / FPS - time.monotonic()))


def session() -> Session:
    return Session(out_dir=Path("."), offline=False)


def test_trajectory_reaches_the_wire_within_one_tick() -> None:
    frames = trajectory(45)
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port))
        backend.open(SPEC, session())
        first = len(emu.goal_log)
        drive(backend, frames)
        backend.close()  # after it, the emulator has surely parsed the last frame's SYNC_WRITE
        sent = emu.goal_log[first:]
        report = backend.report()
    for servo_id in range(1, 8):
        got = [g.tick for g in sent if g.servo_id == servo_id][: len(frames)]
        want = [expected_ticks(v)[servo_id] for v in frames]
        assert len(got) == len(frames)
        assert np.max(np.abs(np.array(got) - np.array(want))) <= 1, servo_id
    # One SYNC_WRITE per frame: the seven goals of a frame came in one packet.
    per_frame = np.array([g.packet for g in sent[: 7 * len(frames)]]).reshape(len(frames), 7)
    assert all(g.inst == dp.SYNC_WRITE for g in sent[: 7 * len(frames)])
    assert np.all(per_frame == per_frame[:, :1]) and len(set(per_frame[:, 0])) == len(frames)
    assert report["status"] == "ok" and report["faults"] == [] and report["frames"] == len(frames), report["faults"]
    assert report["torque_off"] and all(not emu.servo(i).torque for i in range(1, 8))
    assert report["servos"]["neck_pan"]["temperature_c"] == 30 and report["bus_ms"]["write"]["n"] >= len(frames)


def test_health_reads_come_right_after_a_frames_goals() -> None:
    """The bus carries one exchange at a time, so a frame due during a health read waits for the
    read's replies. While frames flow, the backend reads right after a frame's goals went out, and
    ``send`` says when they did."""
    frames = trajectory(60)
    period = 1 / FPS
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port, read_rate=10))
        backend.open(SPEC, session())
        start = time.monotonic()
        for i, values in enumerate(frames):
            before = time.monotonic()
            left = backend.send(TargetFrame(i, i / FPS, values, ()))
            assert left is not None and before <= left <= time.monotonic()
            time.sleep(max(0.0, start + (i + 1) / FPS - time.monotonic()))
        end = time.monotonic()
        backend.close()
    goals = np.array(sorted({g.time for g in emu.goal_log if g.inst == dp.SYNC_WRITE and start <= g.time <= end}))
    reads = np.array([t for t in emu.sync_read_times if goals[0] < t < end])
    assert len(reads) >= 10, "about ten reads a second"
    since_goals = reads - goals[np.searchsorted(goals, reads) - 1]
    assert np.median(since_goals) < period / 4 and np.mean(since_goals < period / 2) >= 0.9, since_goals


def test_close_eases_to_neutral_then_torque_off() -> None:
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port))
        backend.open(SPEC, session())
        away = np.clip(SPEC.neutral + 0.3, SPEC.lower, SPEC.upper)
        first = len(emu.goal_log)
        drive(backend, np.linspace(SPEC.neutral, away, 10))
        # The frames went out before drive returned; the emulator may still be parsing the last
        # ones, which must not count as the ease's (the ramp moves away from neutral).
        wait_for(lambda: sum(g.servo_id == 1 for g in emu.goal_log[first:]) >= 10, "the ramp's 10 frames")
        before = len(emu.goal_log)
        t0 = time.monotonic()
        backend.close()
        took = time.monotonic() - t0
        tail = [g for g in emu.goal_log[before:] if g.servo_id == 1]
        torque = [t for t in emu.torque_log if t.value == 0 and t.time >= t0]
    neutral = expected_ticks(SPEC.neutral)[1]
    start = expected_ticks(away)[1]
    ticks = [g.tick for g in tail]
    assert ticks[-1] == neutral and len(ticks) >= 5  # several steps, not a jump
    assert all(abs(b - neutral) <= abs(a - neutral) for a, b in zip(ticks, ticks[1:]))
    assert abs(ticks[0] - start) < abs(start - neutral) / 3  # the first step is small: eased
    assert 0.25 <= took < 2.0
    assert {t.servo_id for t in torque} == set(range(1, 8))
    assert min(t.time for t in torque) >= tail[-1].time


def test_watchdog_eases_to_neutral_when_frames_stop() -> None:
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port))
        backend.open(SPEC, session())
        away = np.clip(SPEC.neutral - 0.25, SPEC.lower, SPEC.upper)
        drive(backend, np.linspace(SPEC.neutral, away, 6))
        last_frame = emu.goal_log[-1].time
        time.sleep(1.0)
        health = backend.health()
        after = [g for g in emu.goal_log if g.time > last_frame + 1e-6 and g.servo_id == 1]
        backend.close()
    assert health["watchdog_trips"] == 1
    assert after, "the watchdog sent nothing"
    assert after[0].time - last_frame >= 0.45
    assert after[-1].tick == expected_ticks(SPEC.neutral)[1]


def _expect_fault(report: dict, name: str) -> None:
    assert report["status"] == "degraded", report["faults"]
    assert any(f.startswith(name) for f in report["faults"]), report["faults"]


@pytest.mark.parametrize("fault", ["drop", "corrupt", "overload", "overheating", "input_voltage", "vanish", "unplug"])
def test_each_fault_degrades_completes_and_ends_torque_off(
    fault: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    link = str(tmp_path / "ttyDXL")
    frames = trajectory(30)
    with DynamixelEmulator(range(1, 8), "xl330", link=link) as emu:
        backend = DynamixelBackend(options(emu.port, latency_ms=16))
        backend.open(SPEC, session())

        def inject(i: int) -> None:
            if i != 5:
                return
            if fault == "drop":
                emu.drop_replies(3, servo_id=4)
            elif fault == "corrupt":
                emu.corrupt_replies(2, servo_id=2)
            elif fault == "vanish":
                emu.vanish(3, seconds=0.35)
            elif fault == "unplug":
                emu.unplug(seconds=0.3)
            else:
                emu.hardware_error(5, fault)

        drive(backend, frames, inject)
        time.sleep(0.15)  # let one more health read see the fault
        health = backend.health()
        closing_at = time.time()
        backend.close()  # must not raise
        report = backend.report()
        torque = {i: emu.servo(i).torque for i in range(1, 8)}
    expected = {
        "drop": "lost_replies:jaw",
        "corrupt": "bad_crc:neck_tilt",
        "vanish": "servo_lost:neck_roll",
        "unplug": "port_lost",
    }.get(fault, f"{fault}:eye_pan")
    _expect_fault(report, expected)
    kind, _, joint = expected.partition(":")
    named = f"dynamixel: {kind} {joint}:" if joint else f"dynamixel: {kind}:"
    logged = [r for r in caplog.records if r.levelname == "WARNING" and r.getMessage().startswith(named)]
    assert logged, "the fault is logged"
    assert logged[0].created < closing_at, "as it happens, not only in the report at the end"
    assert health["status"] in ("ok", "degraded")
    assert report["frames"] == len(frames)
    assert report["torque_off"] and not any(torque.values())
    if fault == "vanish":
        assert any(e["event"] == "servo_recovered" for e in report["events"])
    if fault == "unplug":
        assert any(e["event"] == "port_recovered" for e in report["events"])


def test_port_gone_for_good_still_completes(tmp_path: Path) -> None:
    # Under a link of its own: a bare /dev/pts/N freed by the unplug can be handed to another
    # test's emulator at once, and the backend's reconnect would then find a head there.
    with start_emulated_head(link=str(tmp_path / "ttyDXL")) as emu:
        backend = DynamixelBackend(options(emu.port, ease_s=0.1))
        backend.open(SPEC, session())
        drive(backend, trajectory(6), lambda i: emu.unplug() if i == 2 else None)
        backend.close()
        report = backend.report()
    assert "port_lost" in report["faults"]
    assert report["status"] == "failed" and report["torque_off"] is False
    assert report["frames_unsent"] >= 1


def test_refuses_frames_outside_limits() -> None:
    with start_emulated_head() as emu:
        backend = DynamixelBackend(options(emu.port))
        backend.open(SPEC, session())
        n = len(emu.goal_log)
        bad = SPEC.neutral.copy()
        bad[0] = SPEC.upper[0] + 0.2
        backend.send(TargetFrame(0, 0.0, bad, ()))
        nan = SPEC.neutral.copy()
        nan[3] = np.nan
        backend.send(TargetFrame(1, 1 / FPS, nan, ()))
        time.sleep(0.1)
        refused_writes = len(emu.goal_log) - n
        health = backend.health()
        backend.close()
        report = backend.report()
    assert refused_writes == 0 and report["frames_refused"] == 2
    # defect 7: refused frames once left the report "ok" while the head never moved
    assert health["status"] == "degraded" and "frames_refused" in health["active_faults"]
    assert report["status"] == "degraded" and "frame_refused" in report["faults"]


def test_user_errors_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="cannot open serial port"):
        DynamixelBackend(options(str(tmp_path / "nope"))).open(SPEC, session())
    with start_emulated_head(ids=[20, 21]) as emu:
        with pytest.raises(UserError, match="no servo answers"):
            DynamixelBackend(options(emu.port)).open(SPEC, session())
    with start_emulated_head(model="xm430") as emu:
        with pytest.raises(UserError, match="xm430-w350, the profile says xl330"):
            DynamixelBackend(options(emu.port)).open(SPEC, session())
    with pytest.raises(UserError, match="port"):
        DynamixelBackend({}).open(SPEC, session())


def test_xl320_table_drives_two_byte_goals() -> None:
    """The XL-320 (own control table: 2-byte goal at 30, 1024 ticks over 300 degrees)."""
    names = ("neck_pan", "neck_tilt")
    joints = {"neck_pan": {"id": 1}, "neck_tilt": {"id": 2, "direction": -1}}
    with start_emulated_head(ids=[1, 2], model="xl320") as emu:
        backend = DynamixelBackend({"port": emu.port, "model": "xl320", "joints": joints, "ease_s": 0.2})
        free = dataclasses.replace(SPEC, max_velocity=np.full(7, np.inf), max_acceleration=np.full(7, np.inf))
        backend.open(free, session())
        values = SPEC.neutral.copy()
        values[SPEC.index["neck_pan"]], values[SPEC.index["neck_tilt"]] = 0.5, 0.3
        n = len(emu.goal_log)
        backend.send(TargetFrame(0, 0.0, values, ()))
        deadline = time.monotonic() + 2.0
        while len(emu.goal_log) < n + 2 and time.monotonic() < deadline:
            time.sleep(0.005)  # SYNC_WRITE has no reply: wait for the emulator to take it
        goals = {g.servo_id: g.tick for g in emu.goal_log[n : n + 2]}
        limits = (emu.servo(1).get("CW_Angle_Limit"), emu.servo(1).get("CCW_Angle_Limit"))
        backend.close()
        report = backend.report()
    per_rad = 1024 / np.radians(300)
    assert goals == {1: round(512 + 0.5 * per_rad), 2: round(512 - 0.3 * per_rad)}
    assert limits == (int(np.floor(512 - 1.4 * per_rad)), int(np.ceil(512 + 1.4 * per_rad)))
    assert report["status"] == "ok" and report["torque_off"] and set(report["servos"]) == set(names)


@needs_realtime
def test_a_servo_childs_bus_threads_share_its_real_time_priority() -> None:
    """In a real-time run the head answers frames from a child process under SCHED_FIFO below the
    clock. Its supervisor polls the bus and holds the bus lock and the interpreter lock that the
    next frame waits for: at ordinary priority a loaded machine preempted it with both held, and
    the head dropped frames. So its threads run real-time too (not a native pool that numpy
    started before: it never holds the interpreter lock)."""
    import os

    from convodrive.plumbing.priority import HELPER_FIFO_PRIORITY
    from convodrive.scheduler.process import ProcessBackend

    with start_emulated_head() as emu:
        backend = ProcessBackend(DynamixelBackend(options(emu.port)))
        backend.open(SPEC, session())
        try:
            before = time.monotonic()
            left = backend.send(TargetFrame(0, 0.0, SPEC.neutral.copy(), ()))
            assert left is not None and before < left < time.monotonic(), "the child says when the goals left"
            assert backend._process is not None
            threads = [int(t) for t in os.listdir(f"/proc/{backend._process.pid}/task")]
            policies = [
                (os.sched_getscheduler(t) & ~os.SCHED_RESET_ON_FORK, os.sched_getparam(t).sched_priority)
                for t in threads
            ]
        finally:
            backend.close()
    realtime = policies.count((os.SCHED_FIFO, HELPER_FIFO_PRIORITY))
    assert realtime >= 2, f"the frames' thread and the supervisor: {policies}"
