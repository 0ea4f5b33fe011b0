"""The name-addressed bus against malformed replies from the emulated servos (real SDK, real pty)."""

from __future__ import annotations

import time

import pytest

from tests.backends.servo import BUS_LATENCY_MS
from tests.conftest import require

pytestmark = require("hardware")

from convodrive.backends.servo.dynamixel_bus import DynamixelBus, Motor  # noqa: E402
from convodrive.backends.servo.dynamixel_emulator import DynamixelEmulator  # noqa: E402
from convodrive.backends.servo.dynamixel_table import model  # noqa: E402
from convodrive.backends.servo.emulator_faults import parse_fault  # noqa: E402
from convodrive.plumbing.errors import UserError  # noqa: E402

XL330 = model("xl330")


@pytest.fixture()
def head():
    with DynamixelEmulator(range(1, 4), "xl330") as emu:
        bus = DynamixelBus(emu.port, [Motor(f"m{i}", i, XL330) for i in range(1, 4)], latency_ms=BUS_LATENCY_MS)
        bus.connect()
        yield emu, bus
        bus.disconnect()


def test_a_short_reply_is_retried_and_counted_not_raised(head) -> None:
    """The SDK indexes past a status packet with too little data (IndexError); the bus asks again."""
    emu, bus = head
    emu.servo(2).move_by_hand(1234)
    emu.short_replies(1, servo_id=2)
    assert bus.read("Present_Position", "m2") == 1234  # 4 bytes asked, 3 came, then a good reply
    emu.short_replies(1, servo_id=3)
    assert bus.read("Hardware_Error_Status", "m3") == 0  # 1 byte asked, none came
    assert emu.counters["shortened"] == 2
    assert (bus.health["m2"].short, bus.health["m3"].short) == (1, 1)
    assert not bus.health["m2"].lost and bus.connected


def test_a_reply_that_came_on_time_to_a_preempted_reader_is_read_not_lost(head, monkeypatch) -> None:
    """The SDK reads, then looks at the clock: a reader the OS took away between an empty read and
    that look, for longer than the timeout, finds the reply waiting; it is read, not counted lost."""
    emu, bus = head
    port, read = bus.port, bus.port.readPort
    stalls: list[float] = []

    def preempted_read(length: int) -> bytes:
        if not stalls:  # the first read found nothing, then the reader waited for a core past the timeout
            stalls.append(port.packet_timeout)
            time.sleep((port.packet_timeout + 50.0) / 1000.0)
            return b""
        return read(length)

    monkeypatch.setattr(port, "readPort", preempted_read)
    emu.servo(2).move_by_hand(1234)
    assert bus.read("Present_Position", "m2") == 1234
    assert stalls and bus.health["m2"].timeouts == 0 and bus.health["m2"].retries == 0


def test_a_short_reply_in_a_group_read_costs_that_servo_one_retry(head) -> None:
    emu, bus = head
    emu.short_replies(1, servo_id=1)
    data = bus.sync_read(["Present_Position", "Present_Temperature"])
    assert sorted(data) == ["m1", "m2", "m3"]
    assert all(d["Present_Temperature"] == 30 for d in data.values())
    assert bus.health["m1"].short == 1 and bus.health["m2"].short == 0
    assert emu.counters["shortened"] == 1


def test_only_short_replies_make_a_lost_servo_not_an_error(head) -> None:
    emu, bus = head
    emu.short_replies(bus.retries + 1, servo_id=2)
    assert bus.read("Present_Position", "m2") is None
    assert bus.health["m2"].lost and bus.health["m2"].short == bus.retries + 1
    assert bus.ping(2) is not None  # the next exchange is whole again


def test_short_fault_spec() -> None:
    fault = parse_fault("short:0.1@2")
    assert (fault.kind, fault.arg, fault.at) == ("short", 0.1, 2.0)
    with pytest.raises(UserError, match="rate from 0 to 1"):
        parse_fault("short:3")
