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

The port, retries, group reads and health records are ``servo_bus.SerialBus``'s, shared with the
Feetech bus; one bus object must be used by one thread at a time (``lock`` serialises callers).
"""

from __future__ import annotations

from typing import Any

import dynamixel_sdk as sdk

from convodrive.backends.servo.dynamixel_sdk_io import CheckedPacketHandler, LatencyPort
from convodrive.backends.servo.dynamixel_table import Register, decode, encode
from convodrive.backends.servo.serial_port import PortLost, ShortReply
from convodrive.backends.servo.servo_bus import Motor, SerialBus, ServoHealth

__all__ = ["DynamixelBus", "Motor", "ServoHealth"]


class DynamixelBus(SerialBus):
    COMM_RX_CORRUPT = sdk.COMM_RX_CORRUPT
    PKT_ID, PKT_ERROR, PKT_PARAMETER0 = 4, 8, 9  # status packet offsets (PARAMETER0 after the error byte)
    STATUS_OVERHEAD = 11
    FAULT_SOURCE = "Hardware_Error_Status"
    sdk = sdk

    def __init__(self, port: str, motors: list[Motor], **kw: Any) -> None:
        super().__init__(port, motors, **kw)
        self.packets = CheckedPacketHandler()
        self._alert: set[str] = set()

    def _new_port(self) -> LatencyPort:
        return LatencyPort(self.port_name, self.latency_ms)

    def _rx_packet(self, port: Any) -> tuple[list[int], int]:
        return self.packets.rxPacket(port, False)  # type: ignore[no-any-return]

    def _refused(self, error: int) -> bool:
        return bool(error & 0x7F)  # an error number (the alert bit 0x80 is a hardware error)

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
        if reply is None or self._refused(reply[1]):
            return None
        return decode(encode_unsigned(reply[0], reg), reg)

    def write(self, register: str, name: str, value: int) -> bool:
        """True when the servo confirmed the write (a status packet without an error number)."""
        motor = self.motors[name]
        reg = motor.table.reg(register)
        data = encode(int(value), reg)
        reply = self._txrx(name, lambda p: (None, *self.packets.writeTxRx(p, motor.id, reg.address, reg.size, data)))
        return reply is not None and not self._refused(reply[1])

    # ------------------------------------------------------------- health
    def _seen(self, health: ServoHealth, error: int) -> None:
        super()._seen(health, error)
        if not error & 0x80:
            health.hardware_error = 0
            health.faults = ()
        if error & 0x80:
            self._alert.add(health.name)

    def take_alerts(self) -> set[str]:
        """Servos whose status packets carried the hardware-alert bit since the last call."""
        alerts, self._alert = self._alert, set()
        return alerts

    def take_new_faults(self) -> list[tuple[str, str, int]]:
        """(joint, fault, Hardware_Error_Status) for each fault seen for the first time since the
        last call: the status register of every servo whose status packets raised the alert bit."""
        new = []
        for name in sorted(self.take_alerts()):
            status = self.read("Hardware_Error_Status", name)
            if status is not None:
                seen = set(self.health[name].faults_seen)
                self.note_hardware_error(name, status)
                new += [(name, fault, status) for fault in sorted(self.health[name].faults_seen - seen)]
        return new

    def note_hardware_error(self, name: str, status: int) -> None:
        health = self.health[name]
        health.hardware_error = status
        health.faults = tuple(self.motors[name].table.decode_errors(status))
        health.faults_seen.update(health.faults)


def encode_unsigned(value: int, reg: Register) -> list[int]:
    return [(int(value) >> (8 * i)) & 0xFF for i in range(reg.size)]
