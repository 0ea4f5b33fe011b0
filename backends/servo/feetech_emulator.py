"""A stateful Feetech STS/SCS bus on a pseudo-terminal, for tests and for users without a robot.

The real ``scservo_sdk`` opens the pty's slave path as its port. Each servo is a
``feetech_servo.FeetechServo`` (its whole register table, moving toward its goal); this module is
the bus: it frames packets (``feetech_packet``), answers PING, READ, WRITE, REG_WRITE/ACTION,
SYNC_WRITE and SYNC_READ (STS only, as the firmware) and ignores a packet whose checksum is wrong (as
the servos do). Reply timing (Return_Delay_Time, time on the wire) and fault injection are
``bus_emulator.BusEmulator``'s, shared with the Dynamixel emulator.

Faults use the Dynamixel emulator's ``--fault`` grammar (``parse_fault``): lost (``drop``), corrupt
(``corrupt``) and short (``short``) replies, ``overload``/``overheating``/``input_voltage`` on a
servo (its error bit in every status packet, torque off as Unloading_Condition says), a servo that
vanishes (``vanish``, back after ``+D`` with its RAM reset) and a port that disappears (``port``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

from convodrive.backends.servo import feetech_packet as fp
from convodrive.backends.servo.bus_emulator import BusEmulator, Clock, LoggedWrite
from convodrive.backends.servo.emulator_faults import Fault
from convodrive.backends.servo.feetech_servo import FeetechServo
from convodrive.backends.servo.feetech_table import model as lookup_model


class FeetechEmulator(BusEmulator):
    """Servos on one emulated bus. A context manager; ``port`` is the path to open."""

    servos: dict[int, FeetechServo]

    def __init__(
        self,
        ids: Iterable[int] = range(1, 8),
        model: str = "sts3215",
        *,
        baudrate: int = 1_000_000,
        link: str | None = None,
        clock: Clock = time.monotonic,
        seed: int = 0,
        on_torque: Callable[[int, bool, str], None] | None = None,
    ) -> None:
        """``on_torque(servo_id, on, why)`` hears every change of a servo's torque, whoever made it."""
        spec = lookup_model(model)
        super().__init__(
            {i: FeetechServo(i, spec, clock) for i in ids},
            baudrate=baudrate,
            link=link,
            clock=clock,
            seed=seed,
            on_torque=on_torque,
            counters=("checksum_errors_in",),
            name="feetech-emulator",
        )

    def goals(self, servo_id: int) -> list[LoggedWrite]:
        with self._lock:
            return [g for g in self.goal_log if g.servo_id == servo_id]

    # ------------------------------------------------------------- wire
    def _parse(self, buffer: bytearray) -> fp.Packet | None:
        return fp.parse(buffer)

    def _corrupted(self, raw: bytes) -> bytes:
        return raw[:-1] + bytes([raw[-1] ^ 0x5A])

    def _shortened(self, raw: bytes) -> bytes | None:
        return fp.status(raw[2], raw[4], raw[5:-2]) if len(raw) > 6 else None

    # ------------------------------------------------------------- protocol
    def _status(self, servo: FeetechServo, params: bytes = b"") -> tuple[int, bytes]:
        return servo.id, fp.status(servo.id, servo.error, params)

    def _handle(self, p: fp.Packet) -> list[tuple[int, bytes]]:
        if not p.checksum_ok:
            self.counters["checksum_errors_in"] += 1
            return []  # a Feetech servo ignores a packet it cannot trust
        if p.inst == fp.SYNC_WRITE and len(p.params) >= 2:
            address, length = p.params[0], p.params[1]
            for k in range(2, len(p.params) - length, length + 1):
                self._write(p.params[k], address, p.params[k + 1 : k + 1 + length], p.inst)
            return []
        if p.inst == fp.SYNC_READ and len(p.params) >= 2:
            self.sync_read_times.append(self.clock())
            address, length = p.params[0], p.params[1]
            out = []
            for sid in p.params[2:]:
                servo = self._answering(sid)
                data = servo.read(address, length) if servo and servo.table.sync_read else None
                if servo is not None and data is not None:
                    out.append(self._status(servo, data))
            return out
        servo = self._answering(p.servo_id)
        if servo is None:
            if p.servo_id == fp.BROADCAST_ID:
                for s in self.servos.values():
                    if s.alive:
                        self._unicast(s, p.inst, p.params)
            return []
        reply = self._unicast(servo, p.inst, p.params)
        answers = p.inst in (fp.PING, fp.READ) or servo.get("Response_Status_Level") >= 1
        return [self._status(servo, reply)] if reply is not None and answers else []

    def _answering(self, servo_id: int) -> FeetechServo | None:
        servo = self.servos.get(servo_id)
        if servo is not None and not servo.alive:
            self.unanswered[servo_id] += 1
            return None
        return servo

    def _unicast(self, s: FeetechServo, inst: int, params: bytes) -> bytes | None:
        """The reply's data (b"" for a bare status), or None for no reply."""
        if inst == fp.PING or inst == fp.ACTION and s.pending is None:
            return b""
        if inst == fp.READ:
            return s.read(params[0], params[1]) if len(params) == 2 else None
        if inst == fp.WRITE:
            return b"" if len(params) >= 2 and self._write(s.id, params[0], params[1:], inst) else None
        if inst == fp.REG_WRITE:
            s.pending = (params[0], bytes(params[1:])) if len(params) >= 2 else None
            return b""
        if inst == fp.ACTION and s.pending is not None:
            pending, s.pending = s.pending, None
            self._write(s.id, *pending, inst)
            return b""
        if inst == fp.RESET:
            s.factory_reset()
            return b""
        return None

    def _write(self, servo_id: int, address: int, data: bytes, inst: int) -> bool:
        servo = self._answering(servo_id)
        if servo is None:
            return False
        ok = servo.write(address, bytes(data))
        for name, log in (("Goal_Position", self.goal_log), ("Torque_Enable", self.torque_log)):
            reg = servo.table.reg(name)
            if ok and address <= reg.address and reg.address + reg.size <= address + len(data):
                value = servo.table.decode(data[reg.address - address :], reg)
                log.append(LoggedWrite(self.clock(), servo_id, value, inst, self.counters["packets"]))
        return ok


def start_emulated_feetech(
    ids: Iterable[int] = range(1, 8),
    model: str = "sts3215",
    *,
    link: str | None = None,
    faults: Iterable[Fault] = (),
    baudrate: int = 1_000_000,
) -> FeetechEmulator:
    """An emulated Feetech head on a fresh pty, already serving; use as a context manager."""
    emu = FeetechEmulator(ids, model, baudrate=baudrate, link=link)
    for fault in faults:
        emu.check_fault(fault)
    emu.start()
    for fault in faults:
        emu.schedule(fault)
    return emu
