"""Pololu Maestro: protocol bytes, the emulator over a pty with pyserial, and the backend."""

from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import require

pytestmark = require("hardware")

import serial  # noqa: E402

from convodrive.backends.base import Session  # noqa: E402
from convodrive.backends.maestro import MaestroBackend  # noqa: E402
from convodrive.backends.servo import maestro_protocol as mp  # noqa: E402
from convodrive.backends.servo.maestro_emulator import MaestroEmulator, start_emulated_maestro  # noqa: E402
from convodrive.motion.targets import TargetFrame  # noqa: E402
from convodrive.plumbing.errors import UserError  # noqa: E402
from convodrive.retargeting import load_profile  # noqa: E402

PROFILE = load_profile("servo_head")
SPEC = PROFILE.spec
FPS = 30


def test_command_bytes() -> None:
    # 1500 us = 6000 quarter-us = 0b101110_1110000: low 7 bits 0x70, high 7 bits 0x2E.
    assert mp.set_target(0, 6000) == bytes([0x84, 0x00, 0x70, 0x2E])
    assert mp.set_speed(5, 140) == bytes([0x87, 0x05, 0x0C, 0x01])
    assert mp.set_acceleration(2, 4) == bytes([0x89, 0x02, 0x04, 0x00])
    assert mp.get_position(3) == bytes([0x90, 0x03]) and mp.get_errors() == bytes([0xA1])
    assert mp.pololu(12, mp.set_target(0, 6000)) == bytes([0xAA, 0x0C, 0x04, 0x00, 0x70, 0x2E])
    assert mp.decode_errors(0b10010) == ["serial_overrun", "serial_protocol"]
    with pytest.raises(ValueError):
        mp.set_target(0, 1 << 14)


def test_emulator_over_pyserial() -> None:
    with MaestroEmulator(6) as emu, serial.Serial(emu.port, 115200, timeout=0.2) as port:
        port.write(mp.set_speed(1, 100) + mp.set_target(1, 6000) + mp.set_target(1, 7000))
        port.write(mp.get_position(1))
        first = port.read(2)
        assert 6000 <= int.from_bytes(first, "little") < 6100  # speed-limited: just left 6000
        time.sleep(0.12)  # 100 * 0.25 us per 10 ms = 1000 quarter-us per 0.1 s
        port.write(mp.get_position(1))
        assert int.from_bytes(port.read(2), "little") == 7000
        port.write(mp.pololu(12, mp.set_target(2, 5000)) + mp.pololu(7, mp.set_target(2, 4000)))
        port.write(bytes([0x05]) + mp.get_errors())  # a stray data byte: protocol error
        assert int.from_bytes(port.read(2), "little") == 1 << 4
        port.write(mp.get_errors())
        assert port.read(2) == b"\x00\x00"  # reading clears
        emu.drop_replies(1)
        port.write(mp.get_position(2))
        assert port.read(2) == b""
        port.write(mp.get_position(2))
        assert int.from_bytes(port.read(2), "little") == 5000  # the other device's command ignored
    assert [t.target for t in emu.targets(1)] == [6000, 7000]


def _backend(port: str, **extra: object) -> MaestroBackend:
    opts = PROFILE.backend_options("maestro")
    opts.update({"port": port, "ease_s": 0.3, "read_rate": 20, **extra})
    backend = MaestroBackend(opts)
    backend.open(SPEC, Session(out_dir=Path("."), offline=False))
    return backend


def _expected_quarter_us(values: np.ndarray) -> list[int]:
    joints = PROFILE.backend_options("maestro")["joints"]
    return [int(round(4 * (joints[n]["zero_us"] + joints[n]["us_per_unit"] * v))) for n, v in zip(SPEC.names, values)]


def test_backend_follows_calibration_and_ends_off() -> None:
    t = np.arange(30)[:, None] / FPS
    frames = np.clip(
        0.3 * (SPEC.upper - SPEC.lower) * np.sin(2 * np.pi * 0.4 * t + np.arange(7)) * np.minimum(1, t),
        SPEC.lower,
        SPEC.upper,
    )
    with start_emulated_maestro(12) as emu:
        backend = _backend(emu.port)
        start = len(emu.target_log)
        t0 = time.monotonic()
        for i, values in enumerate(frames):
            backend.send(TargetFrame(i, i / FPS, values, ()))
            time.sleep(max(0.0, t0 + (i + 1) / FPS - time.monotonic()))
        sent = emu.target_log[start:]
        emu.raise_error("serial_overrun")
        time.sleep(0.15)
        backend.close()
        report = backend.report()
        final = [c.target for c in emu.channels]
    joints = PROFILE.backend_options("maestro")["joints"]
    for k, name in enumerate(SPEC.names):
        got = [w.target for w in sent if w.channel == joints[name]["channel"]][: len(frames)]
        want = [_expected_quarter_us(v)[k] for v in frames]
        assert np.max(np.abs(np.array(got) - np.array(want))) <= 1, name
        assert all(4 * joints[name]["min_us"] <= g <= 4 * joints[name]["max_us"] for g in got)
    assert "controller_serial_overrun" in report["faults"] and report["status"] == "degraded"
    assert report["torque_off"] and final == [0] * 12


def test_backend_survives_unplug_and_drops(tmp_path: Path) -> None:
    # A link of its own, so the reconnect cannot find another test's pty under a reused /dev/pts/N.
    with MaestroEmulator(12, link=str(tmp_path / "ttyACM0")) as emu:
        backend = _backend(emu.port, ease_s=0.1)
        for i in range(10):
            if i == 3:
                emu.drop_replies(4)
            if i == 6:
                emu.unplug()
            backend.send(TargetFrame(i, i / FPS, SPEC.neutral, ()))
            time.sleep(1 / FPS)
        time.sleep(0.1)
        backend.close()
        report = backend.report()
    assert "port_lost" in report["faults"] and report["status"] == "failed"
    assert report["frames"] == 10 and report["torque_off"] is False


def test_user_errors(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="cannot open serial port"):
        _backend(str(tmp_path / "ttyACM9"))
    with MaestroEmulator(12) as emu:
        emu.drop_replies(1)
        with pytest.raises(UserError, match="no Maestro answers"):
            _backend(emu.port)
    opts = copy.deepcopy(PROFILE.backend_options("maestro"))
    opts["joints"]["jaw"]["min_us"] = 9000
    with pytest.raises(UserError, match="jaw"):
        MaestroBackend({**opts, "port": "/dev/null"}).open(SPEC, Session(out_dir=Path(".")))


def test_pololu_protocol_with_device_number() -> None:
    with start_emulated_maestro(12) as emu:
        backend = _backend(emu.port, device=12)
        values = SPEC.neutral.copy()
        backend.send(TargetFrame(0, 0.0, values, ()))
        deadline = time.monotonic() + 2.0
        while len(emu.targets(0)) < 1 and time.monotonic() < deadline:
            time.sleep(0.005)
        backend.close()
        assert emu.targets(0)[0].target == _expected_quarter_us(values)[0]
        assert backend.report()["torque_off"] and backend.health()["torque_off"] is True


def test_a_channel_the_maestro_does_not_have_is_refused() -> None:
    """Defect 11: a profile channel beyond the controller's was accepted, and its servo never moved."""
    with MaestroEmulator(6) as emu:  # a Micro Maestro: channels 0..5; the profile's eyelids use 6
        with pytest.raises(UserError) as info:
            _backend(emu.port)
    message = str(info.value)
    assert "backends.maestro.joints.eyelids.channel" in message and "channel 6" in message, message
    with pytest.raises(UserError, match=r"option 'joints.eyelids.channel': 6 is not a channel of a 6-channel Maestro"):
        MaestroBackend({**PROFILE.backend_options("maestro"), "channels": 6})
    twice = copy.deepcopy(PROFILE.backend_options("maestro"))
    twice["joints"]["jaw"]["channel"] = 0
    with pytest.raises(UserError, match="channel 0 is used by more than one joint"):
        MaestroBackend(twice)
    with MaestroEmulator(12) as emu:  # declared and present: runs
        backend = _backend(emu.port, channels=12)
        backend.close()
        assert backend.report()["torque_off"]
