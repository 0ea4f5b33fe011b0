"""Name-addressed Feetech STS/SCS bus over the official ``scservo_sdk`` (feetech-servo-sdk).

What the SDK leaves to its callers lives here: registers addressed by name through
``feetech_table`` (which encodes each servo's byte order and sign bits: the SDK keeps one byte
order for the whole process), goal positions for every servo in one SYNC_WRITE, SYNC_READ replies
collected per servo (one silent servo does not blank the others; SCS servos, which have no
SYNC_READ, are read one at a time), retries with back-off on lost or corrupt replies, and a health
record per servo (``dynamixel_bus.ServoHealth``, the same report as the Dynamixel head's).

Feetech status packets carry the servo's fault bits in their error byte on every reply, so there
is no alert-then-read cycle as with Dynamixel: each reply updates the servo's faults. A port-level
failure raises ``PortLost``. One thread at a time: ``lock`` serialises callers.
"""

from __future__ import annotations

import dataclasses
import termios
import threading
import time
from typing import Any

import scservo_sdk as sdk
import serial

from convodrive.backends.servo.dynamixel_bus import ServoHealth
from convodrive.backends.servo.dynamixel_sdk_io import LatencyPort
from convodrive.backends.servo.feetech_table import FeetechTable, Model, identify
from convodrive.backends.servo.serial_port import PortLost, open_error
from convodrive.plumbing.errors import UserError

PKT_ID, PKT_LENGTH, PKT_ERROR, PKT_PARAMETER0 = 2, 3, 4, 5
STATUS_OVERHEAD = 6
"""Bytes of a status packet around its data: header 2, id, length, error, checksum."""


@dataclasses.dataclass(frozen=True)
class Motor:
    name: str
    id: int
    model: Model

    @property
    def table(self) -> FeetechTable:
        return self.model.table


class ShortReply(Exception):
    """A status packet with a valid checksum but less data than the request asked for."""


class FeetechPort(sdk.PortHandler):  # type: ignore[misc]
    """The SDK's port with the Dynamixel port's latency-aware timeouts and non-spinning reads.

    Both SDKs share the port interface; the two methods are ``dynamixel_bus.LatencyPort``'s own."""

    setPacketTimeout = LatencyPort.setPacketTimeout  # noqa: N815 (SDK name)
    readPort = LatencyPort.readPort  # noqa: N815 (SDK name)

    def __init__(self, port_name: str, latency_ms: float) -> None:
        super().__init__(port_name)
        self.latency_ms = latency_ms


class FeetechBus:
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
        self.packets = sdk.PacketHandler(0)  # its word macros are unused: feetech_table encodes
        self.port: FeetechPort | None = None
        self.group_timeouts = 0
        """Group reads that ended before every servo answered (the missing ones are asked alone)."""
        self._new_faults: list[tuple[str, str, int]] = []

    # ------------------------------------------------------------- port
    def connect(self) -> None:
        """Open the port; a missing or unusable port is the user's to fix (UserError)."""
        with self.lock:
            port = FeetechPort(self.port_name, self.latency_ms)
            port.baudrate = self.baudrate
            try:
                ok = port.openPort()
            except (serial.SerialException, OSError) as exc:
                raise open_error(self.port_name, exc) from None
            if not ok:
                raise UserError(f"{self.port_name}: baud rate {self.baudrate} is not supported by scservo_sdk")
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

    def _port(self) -> FeetechPort:
        if self.port is None:
            raise PortLost(f"{self.port_name}: not connected")
        return self.port

    def _guard(self, fn, *args):  # type: ignore[no-untyped-def]
        """Run one SDK call; serial-level failures become PortLost (the dead port dropped)."""
        try:
            return fn(*args)
        except (serial.SerialException, OSError, termios.error, TypeError) as exc:
            self.disconnect()
            raise PortLost(f"{self.port_name}: {exc}") from None
        except IndexError:  # the SDK indexed past a short packet
            if self.port is not None:
                self.port.is_using = False
            raise ShortReply(f"{self.port_name}: a status packet was shorter than asked for") from None

    # ------------------------------------------------------------- single servo
    def ping(self, servo_id: int) -> str | None:
        """The model name of the servo that answers (``unknown(...)`` if not one of ours), or None."""
        with self.lock:
            for _ in range(self.retries + 1):  # a probe keeps no health record, but a lost reply is no absence
                data = self._read_raw(servo_id, 3, 2)
                if data is not None:
                    return identify(data)
        return None

    def _read_raw(self, servo_id: int, address: int, length: int) -> list[int] | None:
        try:
            data, result, _ = self._guard(self._read_span, self._port(), servo_id, address, length)
        except ShortReply:
            return None
        return data if result == sdk.COMM_SUCCESS else None

    def read(self, register: str, name: str) -> int | None:
        motor = self.motors[name]
        reg = motor.table.reg(register)
        data = self._txrx(name, lambda p: self._read_span(p, motor.id, reg.address, reg.size))
        return None if data is None else motor.table.decode(data, reg)

    def write(self, register: str, name: str, value: int) -> bool:
        """True when the servo acknowledged the write."""
        motor = self.motors[name]
        reg = motor.table.reg(register)
        data = list(motor.table.encode(int(value), reg))
        return self._txrx(name, lambda p: (*self.packets.writeTxRx(p, motor.id, reg.address, reg.size, data),)) == []

    def _read_span(self, port: Any, servo_id: int, start: int, length: int) -> tuple[list[int], int]:
        data, result, error = self.packets.readTxRx(port, servo_id, start, length)
        if result == sdk.COMM_SUCCESS and len(data) < length:
            raise ShortReply(f"{len(data)} data bytes, {length} asked for")
        return list(data), result, error  # type: ignore[return-value]

    def _txrx(self, name: str, call) -> list[int] | None:  # type: ignore[no-untyped-def]
        """One request with status, retried with a short back-off: the data ([] for a write) or None."""
        health = self.health[name]
        with self.lock:
            for attempt in range(self.retries + 1):
                if attempt:
                    health.retries += 1
                    time.sleep(0.001 * 2 ** (attempt - 1))
                try:
                    reply = self._guard(call, self._port())
                except ShortReply:  # e.g. a late reply to an earlier, shorter request of this servo
                    health.short += 1
                    continue
                data, (result, error) = (reply[0], reply[1:]) if len(reply) == 3 else ([], reply)
                if result == sdk.COMM_SUCCESS:
                    self._seen(health, error)
                    return data
                self._count(health, result)
            self._failed(health)
            return None

    # ------------------------------------------------------------- group
    def sync_write(self, register: str, values: dict[str, int]) -> None:
        """One SYNC_WRITE packet per register layout (no status packets come back)."""
        for table, names in self._by_table(values).items():
            reg = table.reg(register)
            with self.lock:
                group = sdk.GroupSyncWrite(self._port(), self.packets, reg.address, reg.size)
                for name in names:
                    group.addParam(self.motors[name].id, list(table.encode(int(values[name]), reg)))
                result = self._guard(group.txPacket)
                if result != sdk.COMM_SUCCESS:
                    raise PortLost(f"{self.port_name}: sync write failed ({self.packets.getTxRxResult(result)})")

    def sync_read(self, registers: list[str], names: list[str] | None = None) -> dict[str, dict[str, int]]:
        """A span of registers from many servos: one SYNC_READ (STS), the missing ones asked alone.

        Servos in back-off (lost recently) are skipped until it expires, so a dead servo costs one
        timeout per back-off period instead of one per read."""
        now = time.monotonic()
        wanted = [n for n in (names or list(self.motors)) if self.health[n].backoff_until <= now]
        out: dict[str, dict[str, int]] = {}
        for table, group_names in self._by_table(wanted).items():
            regs = {r: table.reg(r) for r in registers}
            start = min(r.address for r in regs.values())
            length = max(r.address + r.size for r in regs.values()) - start
            raw = self._sync_read_span(group_names, start, length) if table.sync_read else {}
            for name in group_names:
                data = raw.get(name)
                if data is None:
                    motor = self.motors[name]
                    data = self._txrx(name, lambda p, m=motor, s=start, n=length: self._read_span(p, m.id, s, n))
                if data is not None:
                    out[name] = {r: table.decode(data[reg.address - start :], reg) for r, reg in regs.items()}
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
                packet, result = self._guard(self.packets.rxPacket, port)
                sid = packet[PKT_ID] if len(packet) > PKT_ERROR else None
                whole = len(packet) >= STATUS_OVERHEAD + length
                if result == sdk.COMM_SUCCESS and sid in pending and not whole:
                    self.health[by_id[sid]].short += 1  # too little data: asked again alone
                elif result == sdk.COMM_SUCCESS and sid in pending:
                    pending.discard(sid)
                    self._seen(self.health[by_id[sid]], packet[PKT_ERROR])
                    got[by_id[sid]] = list(packet[PKT_PARAMETER0 : PKT_PARAMETER0 + length])
                elif result == sdk.COMM_RX_CORRUPT and sid in pending and whole:
                    self.health[by_id[sid]].corrupt += 1  # whole packet, bad checksum: try the others
                elif result != sdk.COMM_SUCCESS:
                    break
            port.is_using = False
            if pending:
                self.group_timeouts += 1  # one deadline covers the group: a servo is charged only alone
        return got

    def _by_table(self, names) -> dict[FeetechTable, list[str]]:  # type: ignore[no-untyped-def]
        """Group servos by register layout: one group instruction needs one layout and byte order."""
        groups: dict[str, list[str]] = {}
        tables: dict[str, FeetechTable] = {}
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
        faults = tuple(self.motors[health.name].table.decode_errors(error))
        for fault in sorted(set(faults) - health.faults_seen):
            self._new_faults.append((health.name, fault, error))
        health.hardware_error, health.faults = error, faults
        health.faults_seen.update(faults)

    def take_new_faults(self) -> list[tuple[str, str, int]]:
        """(joint, fault, error byte) for each fault seen for the first time since the last call."""
        new, self._new_faults = self._new_faults, []
        return new

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
