"""Name-addressed Dynamixel bus over the official ``dynamixel_sdk`` (Protocol 2.0).

What the SDK leaves to its callers lives here: registers addressed by name through the control
tables, goal positions for every servo in one SYNC_WRITE, SYNC_READ replies collected per servo
(one silent servo does not blank the others), retries with back-off on lost status packets, and
a health record per servo. A port-level failure (adapter unplugged) raises ``PortLost``.

The SDK trusts a status packet with a valid checksum and takes the data it asked for from it, so
a packet shorter than the request (a late reply to an earlier, shorter read, which a loaded host
makes likely) reads its checksum bytes as data, or raises IndexError deep inside it. Here every
reply is measured against its request (``dynamixel_sdk_io.CheckedPacketHandler``), and a short one
is a ``ShortReply``: one bad exchange of one servo, counted and retried like a lost or corrupt one,
never an error of the run.

One bus object must be used by one thread at a time (the SDK's port has a non-reentrant busy
flag); ``lock`` serialises callers.
"""

from __future__ import annotations

import dataclasses
import termios
import threading
import time
from typing import Any

import dynamixel_sdk as sdk
import serial

from convodrive.backends.servo.dynamixel_sdk_io import CheckedPacketHandler, LatencyPort, ShortReply
from convodrive.backends.servo.dynamixel_table import ControlTable, Model, Register, decode, encode
from convodrive.backends.servo.serial_port import PortLost, open_error
from convodrive.plumbing.errors import UserError

PKT_ID, PKT_ERROR, PKT_PARAMETER0 = 4, 8, 9  # status packet offsets (PARAMETER0 after the error byte)


@dataclasses.dataclass(frozen=True)
class Motor:
    name: str
    id: int
    model: Model

    @property
    def table(self) -> ControlTable:
        return self.model.table


@dataclasses.dataclass
class ServoHealth:
    """What the run report says about one servo."""

    name: str
    id: int
    last_seen: float | None = None
    timeouts: int = 0
    corrupt: int = 0
    short: int = 0
    """Status packets shorter than the data asked for."""
    retries: int = 0
    refused: int = 0
    consecutive_failures: int = 0
    lost_events: int = 0
    backoff_until: float = 0.0
    hardware_error: int = 0
    faults: tuple[str, ...] = ()
    faults_seen: set[str] = dataclasses.field(default_factory=set)
    position: int | None = None
    temperature: int | None = None
    voltage: float | None = None

    @property
    def lost(self) -> bool:
        return self.consecutive_failures > 0

    def as_dict(self, now: float | None = None) -> dict[str, Any]:
        now = time.monotonic() if now is None else now
        status = "lost" if self.lost else ("fault" if self.hardware_error else "ok")
        return {
            "id": self.id,
            "status": status,
            "last_seen_s": None if self.last_seen is None else round(now - self.last_seen, 3),
            "timeouts": self.timeouts,
            "corrupt": self.corrupt,
            "short": self.short,
            "retries": self.retries,
            "refused": self.refused,
            "lost_events": self.lost_events,
            "hardware_error": self.hardware_error,
            "faults": list(self.faults),
            "faults_seen": sorted(self.faults_seen),
            "position": self.position,
            "temperature_c": self.temperature,
            "voltage_v": self.voltage,
        }


class DynamixelBus:
    def __init__(
        self,
        port: str,
        motors: list[Motor],
        *,
        baudrate: int = 1_000_000,
        retries: int = 2,
        latency_ms: float = 16.0,
        backoff_s: tuple[float, float] = (0.2, 2.0),
    ) -> None:
        self.port_name = port
        self.baudrate = baudrate
        self.motors = {m.name: m for m in motors}
        self.retries = retries
        self.latency_ms = latency_ms
        self.backoff_s = backoff_s
        self.health = {m.name: ServoHealth(m.name, m.id) for m in motors}
        self.lock = threading.RLock()
        self.packets = CheckedPacketHandler()
        self.port: LatencyPort | None = None
        self._alert: set[str] = set()
        self.group_timeouts = 0
        """Group reads that ended before every servo answered (the missing ones are asked alone)."""

    # ------------------------------------------------------------- port
    def connect(self) -> None:
        """Open the port; a missing or unusable port is the user's to fix (UserError)."""
        with self.lock:
            port = LatencyPort(self.port_name, self.latency_ms)
            port.baudrate = self.baudrate
            try:
                ok = port.openPort()
            except (serial.SerialException, OSError) as exc:
                raise open_error(self.port_name, exc) from None
            if not ok:
                raise UserError(f"{self.port_name}: baud rate {self.baudrate} is not supported")
            self.port = port

    def disconnect(self) -> None:
        with self.lock:
            if self.port is not None:
                try:
                    self.port.closePort()
                except Exception:  # noqa: BLE001 - the port may already be gone
                    pass
                self.port = None

    @property
    def connected(self) -> bool:
        return self.port is not None

    def _port(self) -> LatencyPort:
        if self.port is None:
            raise PortLost(f"{self.port_name}: not connected")
        return self.port

    def _guard(self, fn, *args):  # type: ignore[no-untyped-def]
        """Run one SDK call; turn serial-level failures into PortLost and drop the dead port, and
        the SDK indexing past a short status packet into ShortReply."""
        try:
            return fn(*args)
        except (serial.SerialException, OSError, termios.error, TypeError) as exc:
            # termios.error: flushing a hung-up tty; TypeError: pyserial on a closed fd.
            self.disconnect()
            raise PortLost(f"{self.port_name}: {exc}") from None
        except (IndexError, ShortReply):  # IndexError: the SDK indexed past a short packet (group reads)
            if self.port is not None:
                self.port.is_using = False
            raise ShortReply(f"{self.port_name}: a status packet was shorter than the data asked for") from None

    # ------------------------------------------------------------- single servo
    def ping(self, servo_id: int) -> tuple[int, int] | None:
        """(model number, firmware) or None when nothing answers."""
        with self.lock:
            port = self._port()
            try:
                number, result, _ = self._guard(self.packets.ping, port, servo_id)
                if result != sdk.COMM_SUCCESS:
                    return None
                firmware, result, _ = self._guard(self.packets.read1ByteTxRx, port, servo_id, 6)
            except ShortReply:
                return None
            return number, firmware if result == sdk.COMM_SUCCESS else -1

    def scan(self) -> dict[int, tuple[int, int]]:
        """Every servo on the bus by broadcast ping: id -> (model number, firmware)."""
        with self.lock:
            for attempt in range(self.retries + 1):
                try:
                    found, _ = self._guard(self.packets.broadcastPing, self._port())
                    return {int(i): (int(v[0]), int(v[1])) for i, v in found.items()}
                except ShortReply:
                    if attempt == self.retries:
                        raise PortLost(f"{self.port_name}: every broadcast ping had a malformed reply") from None
            return {}

    def read(self, register: str, name: str) -> int | None:
        motor = self.motors[name]
        reg = motor.table.reg(register)
        fns = {1: self.packets.read1ByteTxRx, 2: self.packets.read2ByteTxRx, 4: self.packets.read4ByteTxRx}
        reply = self._txrx(name, lambda p: fns[reg.size](p, motor.id, reg.address))
        if reply is None or reply[1] & 0x7F:
            return None
        return decode(encode_unsigned(reply[0], reg), reg)

    def write(self, register: str, name: str, value: int) -> bool:
        """True when the servo confirmed the write (a status packet without an error number)."""
        motor = self.motors[name]
        reg = motor.table.reg(register)
        data = encode(int(value), reg)
        reply = self._txrx(name, lambda p: (None, *self.packets.writeTxRx(p, motor.id, reg.address, reg.size, data)))
        return reply is not None and not reply[1] & 0x7F

    def _txrx(self, name: str, call) -> tuple[Any, int] | None:  # type: ignore[no-untyped-def]
        """One request with status, retried with a short back-off: (value, error byte) or None."""
        health = self.health[name]
        with self.lock:
            for attempt in range(self.retries + 1):
                if attempt:
                    health.retries += 1
                    time.sleep(0.001 * 2 ** (attempt - 1))
                try:
                    value, result, error = self._guard(call, self._port())
                except ShortReply:  # e.g. a late reply to an earlier, shorter request of this servo
                    health.short += 1
                    continue
                if result == sdk.COMM_SUCCESS:
                    self._seen(health, error)
                    if error & 0x7F:
                        health.refused += 1  # the servo answered with an error number
                    return value, error
                self._count(health, result)
            self._failed(health)
            return None

    # ------------------------------------------------------------- group
    def sync_write(self, register: str, values: dict[str, int]) -> None:
        """One SYNC_WRITE packet for all servos (no status packets come back)."""
        for table, names in self._by_table(values).items():
            reg = table.reg(register)
            with self.lock:
                group = sdk.GroupSyncWrite(self._port(), self.packets, reg.address, reg.size)
                for name in names:
                    group.addParam(self.motors[name].id, encode(int(values[name]), reg))
                result = self._guard(group.txPacket)
                if result != sdk.COMM_SUCCESS:
                    raise PortLost(f"{self.port_name}: sync write failed ({self.packets.getTxRxResult(result)})")

    def sync_read(self, registers: list[str], names: list[str] | None = None) -> dict[str, dict[str, int]]:
        """Read a span of registers from many servos in one SYNC_READ; missing ones are retried alone.

        Servos in back-off (lost recently) are skipped until their back-off expires, so a dead
        servo costs one timeout per back-off period instead of one per read.
        """
        now = time.monotonic()
        wanted = [n for n in (names or list(self.motors)) if self.health[n].backoff_until <= now]
        out: dict[str, dict[str, int]] = {}
        for table, group_names in self._by_table(wanted).items():
            regs = {r: table.reg(r) for r in registers}
            start = min(r.address for r in regs.values())
            length = max(r.address + r.size for r in regs.values()) - start
            raw = self._sync_read_span(group_names, start, length)
            for name in group_names:
                data = raw.get(name)
                if data is None:  # retry alone, with back-off between attempts
                    motor = self.motors[name]
                    reply = self._txrx(
                        name, lambda p, m=motor, s=start, n=length: _read_span(self.packets, p, m.id, s, n)
                    )
                    data = reply[0] if reply is not None and not reply[1] & 0x7F else None
                if data is not None:
                    out[name] = {r: decode(data[reg.address - start :], reg) for r, reg in regs.items()}
        return out

    def _sync_read_span(self, names: list[str], start: int, length: int) -> dict[str, list[int]]:
        by_id = {self.motors[n].id: n for n in names}
        got: dict[str, list[int]] = {}
        with self.lock:
            port = self._port()
            group = sdk.GroupSyncRead(port, self.packets, start, length)
            for servo_id in by_id:
                group.addParam(servo_id)
            if self._guard(group.txPacket) != sdk.COMM_SUCCESS:
                return got
            pending = set(by_id)
            while pending:
                packet, result = self._guard(self.packets.rxPacket, port, False)
                sid = packet[PKT_ID] if len(packet) > PKT_PARAMETER0 else None
                if result == sdk.COMM_SUCCESS and sid in pending and len(packet) < 11 + length:
                    self.health[by_id[sid]].short += 1  # too little data: that servo is asked again alone
                elif result == sdk.COMM_SUCCESS and sid in pending:
                    pending.discard(sid)
                    self._seen(self.health[by_id[sid]], packet[PKT_ERROR])
                    got[by_id[sid]] = list(packet[PKT_PARAMETER0 : PKT_PARAMETER0 + length])
                elif result == sdk.COMM_RX_CORRUPT and sid in pending and len(packet) >= 11 + length:
                    self.health[by_id[sid]].corrupt += 1  # whole packet, bad CRC: try the others
                elif result != sdk.COMM_SUCCESS:
                    break
            port.is_using = False
            if pending:
                # One deadline covers the whole group's replies, so one slow reply (a loaded
                # host, a noisy bus) leaves every later servo pending. That is one event of the
                # bus; a servo is charged a timeout only when it also fails to answer alone.
                self.group_timeouts += 1
        return got

    def _by_table(self, names) -> dict[ControlTable, list[str]]:  # type: ignore[no-untyped-def]
        """Group servos by control table: one group instruction needs one register layout."""
        groups: dict[str, list[str]] = {}
        tables: dict[str, ControlTable] = {}
        for name in names:
            table = self.motors[name].table
            tables[table.family] = table
            groups.setdefault(table.family, []).append(name)
        return {tables[f]: n for f, n in groups.items()}

    # ------------------------------------------------------------- health
    def _seen(self, health: ServoHealth, error: int) -> None:
        health.last_seen = time.monotonic()
        health.consecutive_failures = 0
        health.backoff_until = 0.0
        if not error & 0x80:
            health.hardware_error = 0
            health.faults = ()
        if error & 0x80:
            self._alert.add(health.name)

    def take_alerts(self) -> set[str]:
        """Servos whose status packets carried the hardware-alert bit since the last call."""
        alerts, self._alert = self._alert, set()
        return alerts

    def _count(self, health: ServoHealth, result: int) -> None:
        if result == sdk.COMM_RX_CORRUPT:
            health.corrupt += 1
        else:
            health.timeouts += 1

    def _failed(self, health: ServoHealth) -> None:
        if not health.lost:
            health.lost_events += 1
        health.consecutive_failures += 1
        lo, hi = self.backoff_s
        health.backoff_until = time.monotonic() + min(hi, lo * 2 ** (health.consecutive_failures - 1))

    def note_hardware_error(self, name: str, status: int) -> None:
        health = self.health[name]
        health.hardware_error = status
        health.faults = tuple(self.motors[name].table.decode_errors(status))
        health.faults_seen.update(health.faults)


def encode_unsigned(value: int, reg: Register) -> list[int]:
    return [(int(value) >> (8 * i)) & 0xFF for i in range(reg.size)]


def _read_span(packets: Any, port: Any, servo_id: int, start: int, length: int) -> tuple[list[int], int, int]:
    return packets.readTxRx(port, servo_id, start, length)
