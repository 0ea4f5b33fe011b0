"""A stateful Dynamixel Protocol 2.0 bus on a pseudo-terminal, for tests and for users without a robot.

The servos on it are ``dynamixel_emulated_servo.EmulatedServo`` (each a whole control table with
a position model); this module parses and answers Protocol 2.0 packets. Reply timing (wire time at
the emulated baud rate, Return_Delay_Time) and fault injection are ``bus_emulator.BusEmulator``'s,
shared with the Feetech emulator.

Faults are injected on demand, through the API or on the command line (``emulator_faults``):
dropped or CRC-corrupted replies, short replies (a well-formed status packet with one data byte too
few, what a reply to an earlier, shorter request looks like when it arrives late), hardware-error
bits (which switch torque off as the Shutdown register says, like a real servo), a servo that
vanishes and comes back, a port that disappears. ``emulated_head`` serves a head from a process
of its own.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable, Iterable

from convodrive.backends.servo import dynamixel_packet as dp
from convodrive.backends.servo.bus_emulator import BusEmulator, Clock, LoggedWrite
from convodrive.backends.servo.dynamixel_emulated_servo import EmulatedServo
from convodrive.backends.servo.dynamixel_table import encode
from convodrive.backends.servo.dynamixel_table import model as lookup_model
from convodrive.backends.servo.emulator_faults import Fault


class DynamixelEmulator(BusEmulator):
    """Servos on one emulated bus. A context manager; ``port`` is the path to open."""

    servos: dict[int, EmulatedServo]

    def __init__(
        self,
        ids: Iterable[int] = range(1, 8),
        model: str = "xl330",
        *,
        baudrate: int = 1_000_000,
        link: str | None = None,
        clock: Clock = time.monotonic,
        seed: int = 0,
        on_torque: Callable[[int, bool, str], None] | None = None,
    ) -> None:
        """``on_torque(servo_id, on, why)`` hears every change of a servo's torque, whoever made it."""
        spec = lookup_model(model)
        servos = {i: EmulatedServo(i, spec, clock) for i in ids}
        counters = ("crc_errors_in", "refused_goals")
        super().__init__(
            servos,
            baudrate=baudrate,
            link=link,
            clock=clock,
            seed=seed,
            on_torque=on_torque,
            counters=counters,
            name="dynamixel-emulator",
        )
        self.requests: collections.Counter[tuple[int, int]] = collections.Counter()
        """Requests each servo was asked to answer, by (servo id, instruction): tests wait on these."""

    def goals(self, servo_id: int, inst: int | None = None) -> list[LoggedWrite]:
        """Goal positions written to one servo, optionally only those a given instruction carried."""
        with self._lock:
            return [g for g in self.goal_log if g.servo_id == servo_id and inst in (None, g.inst)]

    # ------------------------------------------------------------- protocol
    def _parse(self, buffer: bytearray) -> dp.Packet | None:
        return dp.parse(buffer)

    def _corrupted(self, raw: bytes) -> bytes:
        return raw[:-2] + bytes([raw[-2] ^ 0x5A, raw[-1]])

    def _shortened(self, raw: bytes) -> bytes | None:
        body = dp.unstuff(raw[7:-2])  # STATUS, error, data
        return dp.status(raw[4], body[1], body[2:-1]) if len(body) > 2 else None

    def _status(self, servo: EmulatedServo, error: int, params: bytes = b"") -> tuple[int, bytes]:
        if servo.hardware_error:
            error |= dp.ERR_ALERT
        return servo.id, dp.status(servo.id, error, params)

    def _targets(self, servo_id: int) -> list[EmulatedServo]:
        if servo_id == dp.BROADCAST_ID:
            return [s for s in self.servos.values() if s.alive]
        servo = self.servos.get(servo_id)
        return [servo] if servo is not None and servo.alive else []

    def _replies_allowed(self, servo: EmulatedServo, inst: int) -> bool:
        level = servo.get("Status_Return_Level")
        return inst == dp.PING or level >= 2 or (level == 1 and inst in (dp.READ, dp.SYNC_READ, dp.BULK_READ))

    def _handle(self, p: dp.Packet) -> list[tuple[int, bytes]]:
        self._count_request(p)
        targets = self._targets(p.servo_id)
        unicast = p.servo_id != dp.BROADCAST_ID
        if not p.crc_ok:
            self.counters["crc_errors_in"] += 1
            return [self._status(s, dp.ERR_CRC) for s in targets if unicast]
        params = p.params
        if p.inst == dp.PING:
            return [
                self._status(
                    s, 0, bytes(encode(s.model.number, s.table.reg("Model_Number"))) + bytes([s.model.firmware])
                )
                for s in targets
            ]
        if p.inst in (dp.READ, dp.WRITE, dp.REG_WRITE, dp.ACTION, dp.REBOOT, dp.FACTORY_RESET, dp.CLEAR):
            return [
                r
                for s in targets
                if (r := self._unicast(s, p.inst, params)) is not None and unicast and self._replies_allowed(s, p.inst)
            ]
        if p.inst == dp.SYNC_WRITE and len(params) >= 4:
            address, length = _u16(params, 0), _u16(params, 2)
            for k in range(4, len(params) - length, length + 1):
                self._write_logged(params[k], address, params[k + 1 : k + 1 + length], dp.SYNC_WRITE)
            return []
        if p.inst == dp.BULK_WRITE:
            k = 0
            while k + 5 <= len(params):
                sid, address, length = params[k], _u16(params, k + 1), _u16(params, k + 3)
                self._write_logged(sid, address, params[k + 5 : k + 5 + length], dp.BULK_WRITE)
                k += 5 + length
            return []
        if p.inst == dp.SYNC_READ and len(params) >= 4:
            self.sync_read_times.append(self.clock())
            address, length = _u16(params, 0), _u16(params, 2)
            return [self._read_reply(sid, address, length) for sid in params[4:] if self._answers(sid)]
        if p.inst == dp.BULK_READ:
            return [
                self._read_reply(params[k], _u16(params, k + 1), _u16(params, k + 3))
                for k in range(0, len(params) - 4, 5)
                if self._answers(params[k])
            ]
        return [self._status(s, dp.ERR_INSTRUCTION) for s in targets if unicast]

    def _count_request(self, p: dp.Packet) -> None:
        if p.inst == dp.SYNC_READ and len(p.params) >= 4:
            asked = list(p.params[4:])
        elif p.inst == dp.BULK_READ:
            asked = [p.params[k] for k in range(0, len(p.params) - 4, 5)]
        elif p.servo_id != dp.BROADCAST_ID and p.inst not in (dp.SYNC_WRITE, dp.BULK_WRITE):
            asked = [p.servo_id]
        else:
            return
        for servo_id in asked:
            self.requests[(servo_id, p.inst)] += 1
            servo = self.servos.get(servo_id)
            if servo is not None and not servo.alive:
                self.unanswered[servo_id] += 1

    def _answers(self, servo_id: int) -> bool:
        servo = self.servos.get(servo_id)
        return servo is not None and servo.alive

    def _read_reply(self, servo_id: int, address: int, length: int) -> tuple[int, bytes]:
        servo = self.servos[servo_id]
        error, data = servo.read(address, length)
        return self._status(servo, error, data)

    def _unicast(self, s: EmulatedServo, inst: int, params: bytes) -> tuple[int, bytes] | None:
        if inst == dp.READ:
            if len(params) != 4:
                return self._status(s, dp.ERR_DATA_LENGTH)
            return self._read_reply(s.id, _u16(params, 0), _u16(params, 2))
        if inst == dp.WRITE:
            if len(params) < 3:
                return self._status(s, dp.ERR_DATA_LENGTH)
            return self._status(s, self._write_logged(s.id, _u16(params, 0), params[2:]))
        if inst == dp.REG_WRITE:
            s._pending = (_u16(params, 0), bytes(params[2:]))
            return self._status(s, 0)
        if inst == dp.ACTION:
            if s._pending:
                self._write_logged(s.id, *s._pending, dp.ACTION)
                s._pending = None
            return self._status(s, 0)
        if inst == dp.REBOOT:
            s.reboot()
            return self._status(s, 0)
        if inst == dp.FACTORY_RESET:
            s.factory_reset()
            return self._status(s, 0)
        return self._status(s, 0)  # CLEAR: nothing to clear in position mode

    def _write_logged(self, servo_id: int, address: int, data: bytes, inst: int = dp.WRITE) -> int:
        servo = self.servos.get(servo_id)
        if servo is None or not servo.alive:
            return dp.ERR_RESULT_FAIL
        error = servo.write(address, bytes(data))
        for name, log in (("Goal_Position", self.goal_log), ("Torque_Enable", self.torque_log)):
            reg = servo.table.reg(name)
            if reg.address >= address and reg.address + reg.size <= address + len(data):
                if not error:
                    log.append(LoggedWrite(self.clock(), servo_id, servo.get(name), inst, self.counters["packets"]))
                elif name == "Goal_Position":
                    self.counters["refused_goals"] += 1
        return error


def _u16(data: bytes, at: int) -> int:
    return data[at] | (data[at + 1] << 8)


def start_emulated_head(
    ids: Iterable[int] = range(1, 8),
    model: str = "xl330",
    *,
    link: str | None = None,
    faults: Iterable[Fault] = (),
    baudrate: int = 1_000_000,
) -> DynamixelEmulator:
    """An emulated servo head on a fresh pty, already serving. Use as a context manager:

    ``with start_emulated_head() as head: options["port"] = head.port`` ... ``head.goal_log``.
    """
    emu = DynamixelEmulator(ids, model, baudrate=baudrate, link=link).start()
    for fault in faults:
        emu.schedule(fault)
    return emu
