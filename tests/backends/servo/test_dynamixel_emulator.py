"""The Dynamixel emulator against the official dynamixel_sdk, over a real pty."""

from __future__ import annotations

import os
import termios
import time

import pytest

from tests.backends.servo import BUS_LATENCY_MS
from tests.conftest import require

pytestmark = require("hardware")

import dynamixel_sdk as sdk  # noqa: E402
import serial  # noqa: E402

from convodrive.backends.servo import dynamixel_packet as dp  # noqa: E402
from convodrive.backends.servo.dynamixel_emulator import DynamixelEmulator  # noqa: E402
from convodrive.backends.servo.emulator_faults import parse_fault  # noqa: E402
from convodrive.plumbing.errors import UserError  # noqa: E402


@pytest.fixture()
def bus(monkeypatch: pytest.MonkeyPatch):
    # The SDK's own port takes its timeouts from a module constant (16 ms: a 34 ms reply timeout).
    monkeypatch.setattr(sdk.port_handler, "LATENCY_TIMER", BUS_LATENCY_MS)
    with DynamixelEmulator(range(1, 4), "xl330") as emu:
        port = sdk.PortHandler(emu.port)
        assert port.openPort()
        yield emu, port, sdk.PacketHandler(2.0)
        port.closePort()


def test_crc_and_stuffing_agree_with_sdk() -> None:
    ph = sdk.PacketHandler(2.0)
    for data in (b"123456789", os.urandom(64), bytes(range(256))):
        assert dp.crc16(data) == ph.updateCRC(0, list(data), len(data))
    assert dp.crc16(b"123456789") == 0xFEE8  # CRC-16/UMTS check value
    body = bytes([dp.WRITE, 0x70, 0x00, 0xFF, 0xFF, 0xFD, 0x00, 0xFF, 0xFF, 0xFD])
    packet = dp.instruction(1, dp.WRITE, body[1:])
    sdk_packet = [0xFF, 0xFF, 0xFD, 0x00, 1, len(body) + 2, 0, *body, 0, 0]
    sdk_packet = ph.addStuffing(sdk_packet)  # returns a new list when it grows
    assert packet[:-2] == bytes(sdk_packet[: len(packet) - 2])  # same stuffing, same length field
    assert dp.unstuff(dp.stuff(body)) == body
    parsed = dp.parse(bytearray(b"\x00\x01" + packet))
    assert parsed is not None and parsed.crc_ok and parsed.params == body[1:]


def test_ping_read_write_are_stateful(bus) -> None:
    emu, port, ph = bus
    assert ph.ping(port, 2)[:2] == (1200, sdk.COMM_SUCCESS)
    assert ph.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT
    # A value whose bytes need stuffing (FF FF FD) survives the round trip.
    assert ph.write4ByteTxRx(port, 1, 112, 0x00FDFFFF) == (sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, 112)[:2] == (0x00FDFFFF, sdk.COMM_SUCCESS)
    assert ph.write4ByteTxRx(port, 1, 112, 200)[0] == sdk.COMM_SUCCESS
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (sdk.COMM_SUCCESS, 0)
    # EEPROM with torque on: Access Error, value unchanged.
    assert ph.write4ByteTxRx(port, 1, 48, 3000) == (sdk.COMM_SUCCESS, dp.ERR_ACCESS)
    assert ph.read4ByteTxRx(port, 1, 48)[0] == 4095
    # Goal outside the position limits: Data Limit Error, not logged.
    assert ph.write4ByteTxRx(port, 1, 116, 5000) == (sdk.COMM_SUCCESS, dp.ERR_DATA_LIMIT)
    before_write = time.monotonic()  # the emulator moves from when it took the goal, after this
    assert ph.write4ByteTxRx(port, 1, 116, 2448)[0] == sdk.COMM_SUCCESS
    time.sleep(0.1)  # and it answers the read after this
    pos, result, _ = ph.read4ByteTxRx(port, 1, 132)
    speed = 200 * 0.229 / 60 * 4096  # ticks per second at this profile velocity
    assert result == sdk.COMM_SUCCESS
    assert 2048 + 0.1 * speed - 1 <= pos <= 2048 + (time.monotonic() - before_write) * speed + 1
    time.sleep(400 / speed)
    assert ph.read4ByteTxRx(port, 1, 132)[0] == 2448
    assert [g.tick for g in emu.goals(1)] == [2448]


def test_group_instructions_and_reboot(bus) -> None:
    emu, port, ph = bus
    write = sdk.GroupSyncWrite(port, ph, 116, 4)
    for i, tick in ((1, 1000), (2, 2000), (3, 3000)):
        write.addParam(i, list(tick.to_bytes(4, "little")))
    assert write.txPacket() == sdk.COMM_SUCCESS
    read = sdk.GroupSyncRead(port, ph, 116, 4)
    for i in (1, 2, 3):
        read.addParam(i)
    assert read.txRxPacket() == sdk.COMM_SUCCESS
    assert [read.getData(i, 116, 4) for i in (1, 2, 3)] == [1000, 2000, 3000]
    bulk = sdk.GroupBulkRead(port, ph)
    bulk.addParam(1, 0, 2)
    bulk.addParam(3, 146, 1)
    assert bulk.txRxPacket() == sdk.COMM_SUCCESS
    assert (bulk.getData(1, 0, 2), bulk.getData(3, 146, 1)) == (1200, 30)
    emu.hardware_error(2, "overload")  # Shutdown has bit 5: torque drops, alert bit set
    _, result, error = ph.read1ByteTxRx(port, 2, 70)
    assert result == sdk.COMM_SUCCESS and error & dp.ERR_ALERT
    assert ph.reboot(port, 2)[0] == sdk.COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 2, 70)[:3] == (0, sdk.COMM_SUCCESS, 0)
    assert [(g.servo_id, g.tick) for g in emu.goal_log] == [(1, 1000), (2, 2000), (3, 3000)]


def test_faults_drop_corrupt_vanish_unplug(bus) -> None:
    emu, port, ph = bus
    emu.drop_replies(1, servo_id=1)
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert ph.ping(port, 1)[1] == sdk.COMM_SUCCESS
    emu.corrupt_replies(1)
    assert ph.ping(port, 3)[1] == sdk.COMM_RX_CORRUPT
    emu.vanish(2, seconds=0.2)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT
    time.sleep(0.25)
    assert ph.ping(port, 2)[1] == sdk.COMM_SUCCESS
    emu.unplug()
    with pytest.raises((serial.SerialException, OSError, termios.error)):
        for _ in range(3):
            ph.ping(port, 1)
            port.is_using = False


def test_a_late_reply_is_not_taken_for_the_next_answer() -> None:
    """A busy machine delays a reply past the bus's timeout; it then arrives while the bus waits
    for its next request's answer. Shorter than that answer, it made the SDK raise IndexError,
    which failed the whole backend at open; the bus counts it corrupt and asks again."""
    from convodrive.backends.servo.dynamixel_bus import DynamixelBus, Motor
    from convodrive.backends.servo.dynamixel_table import model

    with DynamixelEmulator([1], "xl330") as emu:
        # Timeouts of 2 * 25 + 2 ms: the first read gives up at ~52 ms, its reply comes at ~80 ms,
        # in the middle of the second read's wait.
        bus = DynamixelBus(emu.port, [Motor("jaw", 1, model("xl330"))], latency_ms=25.0, retries=0)
        bus.connect()
        try:
            emu.delay_replies(0.08, servo_id=1)
            assert bus.read("Firmware_Version", "jaw") is None
            bus.retries = 1
            assert bus.read("Present_Position", "jaw") == 2048  # asked again after the stale reply
            assert bus.health["jaw"].short == 1 and bus.health["jaw"].timeouts == 1
        finally:
            bus.disconnect()


def test_fault_specs_parse() -> None:
    f = parse_fault("vanish:4@1.5+2")
    assert (f.kind, f.arg, f.at, f.duration) == ("vanish", 4.0, 1.5, 2.0)
    assert parse_fault("port@3").duration is None
    with pytest.raises(UserError):
        parse_fault("melt:1")
