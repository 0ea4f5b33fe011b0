"""A stateful Feetech STS/SCS bus on a pseudo-terminal, for tests and for users without a robot.

The real ``scservo_sdk`` opens the pty's slave path as its port. Each servo is a
``feetech_servo.FeetechServo`` (its whole register table, moving toward its goal); this module is
the bus: it frames packets (``feetech_packet``), answers PING, READ, WRITE, REG_WRITE/ACTION,
SYNC_WRITE and SYNC_READ (STS only, as the firmware), ignores a packet whose checksum is wrong (as
the servos do), and delays each reply by Return_Delay_Time and its time on the wire.

Faults use the Dynamixel emulator's ``--fault`` grammar (``parse_fault``): lost (``drop``), corrupt
(``corrupt``) and short (``short``) replies, ``overload``/``overheating``/``input_voltage`` on a
servo (its error bit in every status packet, torque off as Unloading_Condition says), a servo that
vanishes (``vanish``, back after ``+D`` with its RAM reset) and a port that disappears (``port``).
"""

from __future__ import annotations

import collections
import dataclasses
import random
import threading
import time
from collections.abc import Callable, Iterable

from convodrive.backends.servo import feetech_packet as fp
from convodrive.backends.servo.emulator_faults import SERVO_FAULTS, Fault
from convodrive.backends.servo.feetech_servo import Clock, FeetechServo
from convodrive.backends.servo.feetech_table import model as lookup_model
from convodrive.backends.servo.pty_server import PtyDevice, PtyServer
from convodrive.plumbing.errors import UserError


@dataclasses.dataclass
class LoggedWrite:
    """One goal or torque write as the servo got it (emulator clock), before any clamping."""

    time: float
    servo_id: int
    value: int
    inst: int
    packet: int
    """Ordinal of the packet that carried it: the goals of one SYNC_WRITE share it."""


class FeetechEmulator(PtyDevice):
    """Servos on one emulated bus. A context manager; ``port`` is the path to open."""

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
        self.clock = clock
        self.baudrate = baudrate
        self.servos = {i: FeetechServo(i, spec, clock) for i in ids}
        self.goal_log: list[LoggedWrite] = []
        self.torque_log: list[LoggedWrite] = []
        self.sync_read_times: list[float] = []
        self.counters = collections.Counter(
            {k: 0 for k in ("packets", "replies", "dropped", "corrupted", "shortened", "checksum_errors_in")}
        )
        self.unanswered: collections.Counter[int] = collections.Counter()
        """Requests to a servo that had vanished, by servo id."""
        self.drop_rate = self.corrupt_rate = self.short_rate = 0.0
        self._lock = threading.RLock()
        self._buffer = bytearray()
        self._rng = random.Random(seed)
        self._pending: dict[str, dict[int | None, int]] = {"drop": {}, "corrupt": {}, "short": {}}
        self._server = PtyServer(self._on_bytes, link=link, name="feetech-emulator")
        self._on_torque = on_torque
        self._torque = {i: s.torque for i, s in self.servos.items()}

    def servo(self, servo_id: int) -> FeetechServo:
        return self.servos[servo_id]

    def goals(self, servo_id: int) -> list[LoggedWrite]:
        with self._lock:
            return [g for g in self.goal_log if g.servo_id == servo_id]

    # ------------------------------------------------------------- faults
    def drop_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        """Swallow the next ``count`` replies (of one servo, or of any)."""
        self._queue("drop", count, servo_id)

    def corrupt_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        self._queue("corrupt", count, servo_id)

    def short_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        """Cut the last data byte off the next ``count`` replies that carry data (checksum kept valid)."""
        self._queue("short", count, servo_id)

    def _queue(self, kind: str, count: int, servo_id: int | None) -> None:
        with self._lock:
            self._pending[kind][servo_id] = self._pending[kind].get(servo_id, 0) + count

    def hardware_error(self, servo_id: int, fault: str) -> None:
        with self._lock:
            self.servos[servo_id].set_error(fault)
            self._torque_changed(f"fault: {fault}")

    def vanish(self, servo_id: int, seconds: float | None = None) -> None:
        """The servo stops answering (cable pulled); back after ``seconds`` if given."""
        self.servos[servo_id].alive = False
        if seconds is not None:
            self._server.after(seconds, lambda: self.reappear(servo_id))

    def reappear(self, servo_id: int) -> None:
        with self._lock:
            servo = self.servos[servo_id]
            servo.alive = True
            servo.power_cycle()
            self._torque_changed("power came back")

    def unplug(self, seconds: float | None = None) -> None:
        """The USB adapter disappears; with ``seconds`` it comes back under the same link."""
        self._server.unplug(seconds)

    def schedule(self, fault: Fault) -> None:
        """Apply ``fault`` ``fault.at`` seconds from now (checked now, not in the timer thread)."""
        self.check_fault(fault)
        self._server.after(fault.at, lambda: fault.apply(self))  # type: ignore[arg-type]

    def check_fault(self, fault: Fault) -> None:
        if fault.kind not in SERVO_FAULTS:
            return
        if fault.servo_id not in self.servos:
            ids = ", ".join(map(str, sorted(self.servos))) or "none"
            raise UserError(f"--fault {fault}: no servo {fault.servo_id} on the emulated bus (ids: {ids})")
        errors = self.servos[fault.servo_id].table.error_bits.values()
        if fault.kind != "vanish" and fault.kind not in errors:
            raise UserError(f"--fault {fault}: a Feetech servo has no {fault.kind} fault (it has: {', '.join(errors)})")

    # ------------------------------------------------------------- wire
    def _on_bytes(self, data: bytes) -> None:
        arrived = time.perf_counter()
        with self._lock:
            self._buffer.extend(data)
            replies: list[tuple[int, bytes]] = []
            request_bytes = 0
            while (packet := fp.parse(self._buffer)) is not None:
                self.counters["packets"] += 1
                request_bytes += packet.size
                replies.extend(self._handle(packet))
            self._torque_changed("commanded")
            out = [(self._delay_s(sid), self._mangle(sid, raw)) for sid, raw in replies]
        due = arrived + self._wire_s(request_bytes)
        for delay, raw in out:
            due += delay  # Return_Delay_Time: the servo waits before it answers
            if raw is None:
                continue
            due += self._wire_s(len(raw))
            self._wait_until(due)
            self._server.send(raw)
            self.counters["replies"] += 1

    def _torque_changed(self, why: str) -> None:
        for servo_id, servo in self.servos.items():
            on = servo.torque
            if on != self._torque[servo_id]:
                self._torque[servo_id] = on
                if self._on_torque is not None:
                    self._on_torque(servo_id, on, why)

    def _delay_s(self, servo_id: int) -> float:
        return 2e-6 * self.servos[servo_id].get("Return_Delay_Time")

    def _wire_s(self, nbytes: int) -> float:
        """Time ``nbytes`` take on the emulated wire (10 bits per byte; 0 if not emulated)."""
        return nbytes * 10.0 / self.baudrate if self.baudrate else 0.0

    def _wait_until(self, due: float) -> None:
        delay = due - time.perf_counter()
        if self.baudrate and delay > 0:
            time.sleep(delay)

    def _take(self, kind: str, servo_id: int, rate: float) -> bool:
        """Whether this reply gets fault ``kind``: one queued for it (or any servo), or by chance."""
        for key in (servo_id, None):
            if self._pending[kind].get(key, 0) > 0:
                self._pending[kind][key] -= 1
                return True
        return bool(rate) and self._rng.random() < rate

    def _mangle(self, servo_id: int, raw: bytes) -> bytes | None:
        if self._take("drop", servo_id, self.drop_rate):
            self.counters["dropped"] += 1
            return None
        if self._take("corrupt", servo_id, self.corrupt_rate):
            self.counters["corrupted"] += 1
            return raw[:-1] + bytes([raw[-1] ^ 0x5A])
        if len(raw) > 6 and self._take("short", servo_id, self.short_rate):
            self.counters["shortened"] += 1
            return fp.status(raw[2], raw[4], raw[5:-2])
        return raw

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
