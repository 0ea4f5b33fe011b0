"""Name-addressed Feetech STS/SCS bus over the official ``scservo_sdk`` (feetech-servo-sdk).

What the SDK leaves to its callers lives here: registers addressed by name through
``feetech_table`` (which encodes each servo's byte order and sign bits: the SDK keeps one byte
order for the whole process), goal positions for every servo in one SYNC_WRITE, SYNC_READ replies
collected per servo (one silent servo does not blank the others; SCS servos, which have no
SYNC_READ, are read one at a time), retries with back-off on lost or corrupt replies, and a health
record per servo (``servo_bus.ServoHealth``, the same report as the Dynamixel head's). The port,
retries, group reads and health bookkeeping are ``servo_bus.SerialBus``'s, shared with the Dynamixel
bus; nothing here imports ``dynamixel_sdk``.

Feetech status packets carry the servo's fault bits in their error byte on every reply, so there
is no alert-then-read cycle as with Dynamixel: each reply updates the servo's faults. A port-level
failure raises ``PortLost``. One thread at a time: ``lock`` serialises callers.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import scservo_sdk as sdk

from convodrive.backends.servo import serial_port
from convodrive.backends.servo.feetech_table import STS, identify
from convodrive.backends.servo.serial_port import ShortReply
from convodrive.backends.servo.servo_bus import Motor, SerialBus, ServoHealth

__all__ = ["FeetechBus", "Motor", "ServoHealth"]

FIRMWARE_ADDRESS = STS.reg("Firmware_Major_Version").address  # major, then minor: the same in every series


class FeetechPort(serial_port.LatencyPort, sdk.PortHandler):  # type: ignore[misc]
    """The SDK's port with the latency-aware timeouts and non-spinning reads of ``serial_port``."""


class FeetechBus(SerialBus):
    COMM_RX_CORRUPT = sdk.COMM_RX_CORRUPT
    PKT_ID, PKT_ERROR, PKT_PARAMETER0 = 2, 4, 5
    STATUS_OVERHEAD = 6
    """Bytes of a status packet around its data: header 2, id, length, error, checksum."""
    FAULT_SOURCE = "status error byte"
    sdk = sdk

    def __init__(self, port: str, motors: list[Motor], **kw: Any) -> None:
        super().__init__(port, motors, **kw)
        self.packets = sdk.PacketHandler(0)  # its word macros are unused: feetech_table encodes
        self._new_faults: list[tuple[str, str, int]] = []

    def _new_port(self) -> FeetechPort:
        return FeetechPort(self.port_name, self.latency_ms)

    def _rx_packet(self, port: Any) -> tuple[list[int], int]:
        return self.packets.rxPacket(port)  # type: ignore[no-any-return]

    def _group_read(self, table: Any, names: list[str], start: int, length: int) -> dict[str, list[int]]:
        return self._sync_read_span(names, start, length) if table.sync_read else {}  # SCS: one READ each

    # ------------------------------------------------------------- single servo
    def ping(self, servo_id: int) -> str | None:
        """The model name of the servo that answers (``unknown(...)`` if not one of ours), or None."""
        with self.lock:
            for _ in range(self.retries + 1):  # a probe keeps no health record, but a lost reply is no absence
                data = self._read_raw(servo_id, 3, 2)
                if data is not None:
                    return identify(data)
        return None

    def scan(self, ids: Iterable[int] = range(253)) -> dict[int, tuple[str, str]]:
        """Every servo among ``ids`` that answers a ping, one id at a time (Feetech servos have no
        broadcast ping): id -> (model name, firmware "major.minor")."""
        found = {}
        for servo_id in ids:
            model = self.ping(servo_id)
            if model is not None:
                firmware = self._read_raw(servo_id, FIRMWARE_ADDRESS, 2)
                found[servo_id] = (model, "-" if firmware is None else f"{firmware[0]}.{firmware[1]}")
        return found

    def _read_raw(self, servo_id: int, address: int, length: int) -> list[int] | None:
        try:
            data, result, _ = self._guard(self._read_span, self._port(), servo_id, address, length)
        except ShortReply:
            return None
        return data if result == sdk.COMM_SUCCESS else None

    def read(self, register: str, name: str) -> int | None:
        motor = self.motors[name]
        reg = motor.table.reg(register)
        reply = self._txrx(name, lambda p: self._read_span(p, motor.id, reg.address, reg.size))
        return None if reply is None else motor.table.decode(reply[0], reg)

    def write(self, register: str, name: str, value: int) -> bool:
        """True when the servo acknowledged the write."""
        motor = self.motors[name]
        reg = motor.table.reg(register)
        data = list(motor.table.encode(int(value), reg))
        return (
            self._txrx(name, lambda p: (None, *self.packets.writeTxRx(p, motor.id, reg.address, reg.size, data)))
            is not None
        )

    def _read_span(self, port: Any, servo_id: int, start: int, length: int) -> tuple[list[int], int, int]:
        data, result, error = self.packets.readTxRx(port, servo_id, start, length)
        if result == sdk.COMM_SUCCESS and len(data) < length:
            raise ShortReply(f"{len(data)} data bytes, {length} asked for")
        return list(data), result, error

    # ------------------------------------------------------------- health
    def _seen(self, health: ServoHealth, error: int) -> None:
        """Every status packet carries the servo's fault bits: they are its faults now."""
        super()._seen(health, error)
        faults = tuple(self.motors[health.name].table.decode_errors(error))
        for fault in sorted(set(faults) - health.faults_seen):
            self._new_faults.append((health.name, fault, error))
        health.hardware_error, health.faults = error, faults
        health.faults_seen.update(faults)

    def take_new_faults(self) -> list[tuple[str, str, int]]:
        """(joint, fault, error byte) for each fault seen for the first time since the last call."""
        new, self._new_faults = self._new_faults, []
        return new
