"""The Feetech emulator and bus: the real scservo_sdk against the emulated servos over a real pty."""

from __future__ import annotations

import pytest

from tests.backends.servo import BUS_LATENCY_MS
from tests.conftest import require, wait_for

pytestmark = require("hardware")

import scservo_sdk as sdk  # noqa: E402

from convodrive.backends.servo import feetech_packet as fp  # noqa: E402
from convodrive.backends.servo import feetech_table as ft  # noqa: E402
from convodrive.backends.servo.feetech_bus import FeetechBus, Motor  # noqa: E402
from convodrive.backends.servo.feetech_emulator import FeetechEmulator, start_emulated_feetech  # noqa: E402
from convodrive.plumbing.errors import UserError  # noqa: E402

HEALTH = ["Present_Position", "Present_Load", "Present_Voltage", "Present_Temperature"]


def bus_for(emu: FeetechEmulator, model: str = "sts3215", ids=range(1, 8)) -> FeetechBus:
    bus = FeetechBus(emu.port, [Motor(f"s{i}", i, ft.model(model)) for i in ids], latency_ms=BUS_LATENCY_MS)
    bus.connect()
    return bus


@pytest.mark.parametrize("end", [0, 1])
def test_words_and_sign_bits_agree_with_the_sdk(end: int) -> None:
    """The table's encoding is the SDK's own (SCS_MAKEWORD in the series' byte order, SCS_TOHOST)."""
    table = ft.SCS if end else ft.STS
    reg = table.reg("Goal_Position")
    sdk.PacketHandler(end)  # sets the SDK's process-wide byte order
    try:
        for value in (0, 1, 2048, 4095, -1, -300, 32767, -32767):
            data = table.encode(value, reg)
            word = sdk.SCS_MAKEWORD(data[0], data[1])
            assert sdk.SCS_TOHOST(word, 15) == value == table.decode(data, reg)
            assert [sdk.SCS_LOBYTE(sdk.SCS_TOSCS(value, 15)), sdk.SCS_HIBYTE(sdk.SCS_TOSCS(value, 15))] == list(data)
    finally:
        sdk.PacketHandler(0)
    with pytest.raises(ValueError):
        table.encode(-1, table.reg("Present_Voltage"))
    with pytest.raises(ValueError):
        table.encode(1 << 15, reg)


def test_the_sdks_packets_parse_and_the_emulators_checksums_hold() -> None:
    port = type("Port", (), {"is_using": False, "clearPort": lambda s: None, "writePort": lambda s, p: len(p)})()
    sent: list[list[int]] = []
    port.writePort = lambda p: sent.append(list(p)) or len(p)  # type: ignore[attr-defined]
    packets = sdk.PacketHandler(0)
    packets.writeTxOnly(port, 3, 42, 2, [0x00, 0x08])
    buffer = bytearray(b"\x00\xff" + bytes(sent[0]))  # noise before the header is skipped
    p = fp.parse(buffer)
    assert p is not None and p.checksum_ok and (p.servo_id, p.inst, p.params) == (3, fp.WRITE, bytes([42, 0, 8]))
    assert fp.instruction(3, fp.WRITE, bytes([42, 0, 8])) == bytes(sent[0]) and buffer == bytearray()
    bad = bytearray(sent[0])
    bad[-1] ^= 1
    assert fp.parse(bad).checksum_ok is False  # type: ignore[union-attr]


def test_sync_write_then_sync_read_round_trip() -> None:
    with start_emulated_feetech() as emu:
        bus = bus_for(emu)
        assert [bus.ping(i) for i in (1, 7, 9)] == ["sts3215", "sts3215", None]
        for name in bus.motors:
            assert bus.write("Torque_Enable", name, 1)
        goals = {f"s{i}": 2048 + 40 * i - 150 for i in range(1, 8)}
        bus.sync_write("Goal_Position", goals)
        wait_for(
            lambda: all(abs(emu.servo(i).present - goals[f"s{i}"]) < 0.5 for i in range(1, 8)),
            "the moves",
            timeout=30.0,
        )
        data = bus.sync_read(HEALTH)
        bus.disconnect()
    assert {n: d["Present_Position"] for n, d in data.items()} == goals
    assert all(d["Present_Voltage"] == 120 and d["Present_Temperature"] == 30 for d in data.values())
    sync = [g for g in emu.goal_log if g.inst == fp.SYNC_WRITE]
    assert len(sync) == 7 and len({g.packet for g in sync}) == 1, "one SYNC_WRITE carried all seven goals"
    assert len(emu.sync_read_times) == 1 and bus.group_timeouts == 0


def test_scs_servos_are_big_endian_and_read_one_at_a_time() -> None:
    with start_emulated_feetech(range(1, 4), "scs0009") as emu:
        bus = bus_for(emu, "scs0009", range(1, 4))
        assert bus.ping(2) == "scs0009"
        assert bus.write("Torque_Enable", "s2", 1) and bus.write("Goal_Velocity", "s2", 0)
        bus.sync_write("Goal_Position", {"s1": 512, "s2": 700, "s3": 512})
        wait_for(lambda: round(emu.servo(2).present) == 700, "servo 2 to arrive", timeout=30.0)
        data = bus.sync_read(HEALTH)
        bus.disconnect()
    assert emu.servo(2).mem[42:44] == bytes([700 >> 8, 700 & 0xFF])  # high byte first
    assert data["s2"]["Present_Position"] == 700 and data["s1"]["Present_Voltage"] == 60
    assert emu.sync_read_times == [] and bus.group_timeouts == 0


def test_goals_beyond_the_limits_are_clamped_and_eeprom_needs_the_lock_open() -> None:
    with start_emulated_feetech(range(1, 2)) as emu:
        bus = bus_for(emu, ids=[1])
        assert bus.write("Max_Position_Limit", "s1", 3000)  # Lock 1: works until power goes
        assert bus.write("Goal_Position", "s1", 3500)
        assert emu.servo(1).get("Goal_Position") == 3000 and emu.goals(1)[-1].value == 3500
        emu.vanish(1)
        emu.reappear(1)
        assert bus.read("Max_Position_Limit", "s1") == 4095, "not saved with the lock closed"
        assert bus.write("Lock", "s1", 0) and bus.write("Max_Position_Limit", "s1", 3000) and bus.write("Lock", "s1", 1)
        emu.vanish(1)
        emu.reappear(1)
        assert bus.read("Max_Position_Limit", "s1") == 3000
        assert not bus.write("Present_Position", "s1", 10), "read-only: no status packet"
        bus.disconnect()


def test_lost_corrupt_and_short_replies_are_counted_and_retried() -> None:
    with start_emulated_feetech() as emu:
        bus = bus_for(emu)
        emu.drop_replies(1, servo_id=2)
        emu.corrupt_replies(1, servo_id=3)
        emu.short_replies(1, servo_id=4)
        data = bus.sync_read(HEALTH)
        assert set(data) == set(bus.motors), "each servo answered in the group or alone"
        emu.drop_replies(2, servo_id=5)
        assert bus.read("Present_Temperature", "s5") == 30
        emu.vanish(6)
        assert bus.read("Present_Temperature", "s6") is None and bus.health["s6"].lost
        bus.disconnect()
    h = bus.health
    assert h["s3"].corrupt == 1 and h["s4"].short == 1 and h["s5"].timeouts == 2 and h["s5"].retries == 2
    assert h["s6"].timeouts == 3 and emu.unanswered[6] == 3
    assert emu.counters["dropped"] == 3 and emu.counters["corrupted"] == 1 and emu.counters["shortened"] == 1


def test_faults_set_their_bit_in_every_reply_and_unload_as_configured() -> None:
    with start_emulated_feetech() as emu:
        bus = bus_for(emu)
        for name in bus.motors:
            bus.write("Torque_Enable", name, 1)
        emu.hardware_error(2, "overload")
        emu.hardware_error(3, "input_voltage")
        emu.hardware_error(4, "overheating")
        data = bus.sync_read(HEALTH)
        new = bus.take_new_faults()
        again = (bus.sync_read(HEALTH), bus.take_new_faults())[1]
        bus.disconnect()
    assert sorted((n, f) for n, f, _ in new) == [("s2", "overload"), ("s3", "input_voltage"), ("s4", "overheating")]
    assert again == [], "a fault is new once"
    assert data["s2"]["Present_Load"] == 1000 and data["s3"]["Present_Voltage"] == 45
    assert data["s4"]["Present_Temperature"] == 80
    assert not emu.servo(2).torque and emu.servo(3).torque and not emu.servo(4).torque  # Unloading_Condition
    assert bus.health["s2"].as_dict()["status"] == "fault" and bus.health["s1"].as_dict()["status"] == "ok"


def test_a_fault_the_bus_cannot_have_is_refused() -> None:
    from convodrive.backends.servo.emulator_faults import parse_fault

    emu = FeetechEmulator(range(1, 3))
    with pytest.raises(UserError, match="no servo 5"):
        emu.check_fault(parse_fault("overload:5"))
    with pytest.raises(UserError, match="unknown Feetech model"):
        FeetechEmulator(model="xl330")
