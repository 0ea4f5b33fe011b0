"""What every name-addressed serial servo bus shares, without any vendor SDK.

``ServoHealth`` (the per-servo record the run report shows), ``Motor`` (a joint's servo), and
``SerialBus``: the port (open, drop, ``PortLost``), one request retried with back-off, SYNC_READ
replies collected per servo (one silent servo does not blank the others, and a servo in back-off
is skipped), and the health bookkeeping. ``dynamixel_bus`` and ``feetech_bus`` fill in their SDK's
port, packet handler and status-packet layout; nothing here imports an SDK, so one bus's path never
needs the other's (the Feetech backend runs without ``dynamixel_sdk``).

One bus object must be used by one thread at a time (the SDKs' ports have a non-reentrant busy
flag); ``lock`` serialises callers.
"""

from __future__ import annotations

import dataclasses
import termios
import threading
import time
from collections.abc import Callable
from typing import Any

import serial

from convodrive.backends.servo.serial_port import PortLost, ShortReply, open_error
from convodrive.plumbing.errors import UserError

COMM_SUCCESS = 0  # both SDKs' result of an exchange that went through


@dataclasses.dataclass(frozen=True)
class Motor:
    """One joint's servo: its name (the profile joint), bus id and model (``Model`` of its table)."""

    name: str
    id: int
    model: Any

    @property
    def table(self) -> Any:
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


class SerialBus:
    """The bus-neutral half of a servo bus; a subclass gives its SDK's parts (below)."""

    COMM_RX_CORRUPT: int
    """The SDK's result for a reply with a bad checksum."""
    PKT_ID: int
    PKT_ERROR: int
    PKT_PARAMETER0: int
    STATUS_OVERHEAD: int
    """Bytes of a status packet around its data."""
    FAULT_SOURCE: str
    """Where the fault bits of ``take_new_faults`` come from, for the events that name them."""
    sdk: Any
    """The SDK module (``GroupSyncWrite``, ``GroupSyncRead``)."""

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
        self.port: Any = None
        self.packets: Any = None
        self.group_timeouts = 0
        """Group reads that ended before every servo answered (the missing ones are asked alone)."""

    # ------------------------------------------------------------- what a bus gives
    def _new_port(self) -> Any:
        """The SDK's port object for ``port_name`` (not yet open)."""
        raise NotImplementedError

    def _rx_packet(self, port: Any) -> tuple[list[int], int]:
        """One status packet of a group read: (packet, result)."""
        raise NotImplementedError

    def _seen(self, health: ServoHealth, error: int) -> None:
        """A status packet came, with this error byte: the servo is here."""
        health.last_seen = time.monotonic()
        health.consecutive_failures = 0
        health.backoff_until = 0.0

    def ping(self, servo_id: int) -> Any:
        """What the servo says it is, or None when nothing answers."""
        raise NotImplementedError

    def read(self, register: str, name: str) -> int | None:
        raise NotImplementedError

    def write(self, register: str, name: str, value: int) -> bool:
        """True when the servo acknowledged the write."""
        raise NotImplementedError

    def take_new_faults(self) -> list[tuple[str, str, int]]:
        """(joint, fault, fault bits) for each fault seen for the first time since the last call."""
        raise NotImplementedError

    def _refused(self, error: int) -> bool:
        """Whether a status packet's error byte says the servo refused the request."""
        return False

    def _read_span(self, port: Any, servo_id: int, start: int, length: int) -> tuple[list[int], int, int]:
        """READ of ``length`` bytes from ``start``: the SDK's (data, result, error)."""
        return self.packets.readTxRx(port, servo_id, start, length)  # type: ignore[no-any-return]

    def _group_read(self, table: Any, names: list[str], start: int, length: int) -> dict[str, list[int]]:
        return self._sync_read_span(names, start, length)

    # ------------------------------------------------------------- port
    def connect(self) -> None:
        """Open the port; a missing or unusable port is the user's to fix (UserError)."""
        with self.lock:
            port = self._new_port()
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

    def _port(self) -> Any:
        if self.port is None:
            raise PortLost(f"{self.port_name}: not connected")
        return self.port

    def _guard(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Run one SDK call; turn serial-level failures into PortLost and drop the dead port, and
        the SDK indexing past a short status packet into ShortReply."""
        try:
            return fn(*args)
        except (serial.SerialException, OSError, termios.error, TypeError) as exc:
            # termios.error: flushing a hung-up tty; TypeError: pyserial on a closed fd.
            self.disconnect()
            raise PortLost(f"{self.port_name}: {exc}") from None
        except (IndexError, ShortReply):  # IndexError: the SDK indexed past a short packet
            if self.port is not None:
                self.port.is_using = False
            raise ShortReply(f"{self.port_name}: a status packet was shorter than the data asked for") from None

    # ------------------------------------------------------------- one servo
    def _txrx(self, name: str, call: Callable[[Any], tuple[Any, int, int]]) -> tuple[Any, int] | None:
        """One request with status, retried with a short back-off: (value, error byte) or None.
        ``call(port)`` returns the SDK's (value, result, error)."""
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
                if result == COMM_SUCCESS:
                    self._seen(health, error)
                    if self._refused(error):
                        health.refused += 1  # the servo answered with an error number
                    return value, error
                self._count(health, result)
            self._failed(health)
            return None

    # ------------------------------------------------------------- group
    def sync_write(self, register: str, values: dict[str, int]) -> None:
        """One SYNC_WRITE packet per register layout (no status packets come back)."""
        for table, names in self._by_table(values).items():
            reg = table.reg(register)
            with self.lock:
                group = self.sdk.GroupSyncWrite(self._port(), self.packets, reg.address, reg.size)
                for name in names:
                    group.addParam(self.motors[name].id, list(table.encode(int(values[name]), reg)))
                result = self._guard(group.txPacket)
                if result != COMM_SUCCESS:
                    raise PortLost(f"{self.port_name}: sync write failed ({self.packets.getTxRxResult(result)})")

    def sync_read(self, registers: list[str], names: list[str] | None = None) -> dict[str, dict[str, int]]:
        """A span of registers from many servos in one group read; the missing ones asked alone.

        Servos in back-off (lost recently) are skipped until it expires, so a dead servo costs one
        timeout per back-off period instead of one per read."""
        now = time.monotonic()
        wanted = [n for n in (names or list(self.motors)) if self.health[n].backoff_until <= now]
        out: dict[str, dict[str, int]] = {}
        for table, group_names in self._by_table(wanted).items():
            regs = {r: table.reg(r) for r in registers}
            start = min(r.address for r in regs.values())
            length = max(r.address + r.size for r in regs.values()) - start
            raw = self._group_read(table, group_names, start, length)
            for name in group_names:
                data = raw.get(name)
                if data is None:  # asked alone, with back-off between attempts
                    motor = self.motors[name]
                    reply = self._txrx(name, lambda p, m=motor, s=start, n=length: self._read_span(p, m.id, s, n))
                    data = reply[0] if reply is not None and not self._refused(reply[1]) else None
                if data is not None:
                    out[name] = {r: table.decode(data[reg.address - start :], reg) for r, reg in regs.items()}
        return out

    def _sync_read_span(self, names: list[str], start: int, length: int) -> dict[str, list[int]]:
        by_id = {self.motors[n].id: n for n in names}
        got: dict[str, list[int]] = {}
        with self.lock:
            port = self._port()
            group = self.sdk.GroupSyncRead(port, self.packets, start, length)
            for servo_id in by_id:
                group.addParam(servo_id)
            if self._guard(group.txPacket) != COMM_SUCCESS:
                return got
            pending = set(by_id)
            while pending:
                packet, result = self._guard(self._rx_packet, port)
                sid = packet[self.PKT_ID] if len(packet) > self.PKT_PARAMETER0 else None
                whole = len(packet) >= self.STATUS_OVERHEAD + length
                if result == COMM_SUCCESS and sid in pending and not whole:
                    self.health[by_id[sid]].short += 1  # too little data: that servo is asked again alone
                elif result == COMM_SUCCESS and sid in pending:
                    pending.discard(sid)
                    self._seen(self.health[by_id[sid]], packet[self.PKT_ERROR])
                    got[by_id[sid]] = list(packet[self.PKT_PARAMETER0 : self.PKT_PARAMETER0 + length])
                elif result == self.COMM_RX_CORRUPT and sid in pending and whole:
                    self.health[by_id[sid]].corrupt += 1  # whole packet, bad checksum: try the others
                elif result != COMM_SUCCESS:
                    break
            port.is_using = False
            if pending:
                # One deadline covers the whole group's replies, so one slow reply (a loaded
                # host, a noisy bus) leaves every later servo pending. That is one event of the
                # bus; a servo is charged a timeout only when it also fails to answer alone.
                self.group_timeouts += 1
        return got

    def _by_table(self, names: Any) -> dict[Any, list[str]]:
        """Group servos by register layout: one group instruction needs one layout."""
        groups: dict[str, list[str]] = {}
        tables: dict[str, Any] = {}
        for name in names:
            table = self.motors[name].table
            tables[table.family] = table
            groups.setdefault(table.family, []).append(name)
        return {tables[f]: n for f, n in groups.items()}

    # ------------------------------------------------------------- health
    def _count(self, health: ServoHealth, result: int) -> None:
        if result == self.COMM_RX_CORRUPT:
            health.corrupt += 1
        else:
            health.timeouts += 1

    def _failed(self, health: ServoHealth) -> None:
        if not health.lost:
            health.lost_events += 1
        health.consecutive_failures += 1
        lo, hi = self.backoff_s
        health.backoff_until = time.monotonic() + min(hi, lo * 2 ** (health.consecutive_failures - 1))
