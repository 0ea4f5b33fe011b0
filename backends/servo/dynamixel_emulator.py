"""A stateful Dynamixel Protocol 2.0 bus on a pseudo-terminal, for tests and for users without a robot.

The servos on it are ``dynamixel_emulated_servo.EmulatedServo`` (each a whole control table with
a position model). Replies are delayed by their time on the wire at the emulated baud rate.

Faults are injected on demand, through the API or on the command line (``emulator_faults``):
dropped or CRC-corrupted replies, short replies (a well-formed status packet with one data byte too
few, what a reply to an earlier, shorter request looks like when it arrives late), hardware-error
bits (which switch torque off as the Shutdown register says, like a real servo), a servo that
vanishes and comes back, a port that disappears. ``emulated_head`` serves a head from a process
of its own.
"""

from __future__ import annotations

import collections
import random
import threading
import time
from collections.abc import Callable, Iterable

from convodrive.backends.servo import dynamixel_packet as dp
from convodrive.backends.servo.dynamixel_emulated_servo import Clock, EmulatedServo, LoggedWrite
from convodrive.backends.servo.dynamixel_table import encode
from convodrive.backends.servo.dynamixel_table import model as lookup_model
from convodrive.backends.servo.emulator_faults import SERVO_FAULTS, Fault
from convodrive.backends.servo.pty_server import PtyDevice, PtyServer
from convodrive.plumbing.errors import UserError


class DynamixelEmulator(PtyDevice):
    """Servos on one emulated bus. A context manager; ``port`` is the path to open."""

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
        self.clock = clock
        self.baudrate = baudrate
        self.servos: dict[int, EmulatedServo] = {i: EmulatedServo(i, spec, clock) for i in ids}
        self.goal_log: list[LoggedWrite] = []
        self.torque_log: list[LoggedWrite] = []  # every accepted Torque_Enable write
        self.sync_read_times: list[float] = []
        """When each SYNC_READ came in (emulator clock): a driver's reads, against its goals."""
        self.counters = {
            "packets": 0,
            "replies": 0,
            "dropped": 0,
            "corrupted": 0,
            "shortened": 0,
            "crc_errors_in": 0,
            "refused_goals": 0,
        }
        self.requests: collections.Counter[tuple[int, int]] = collections.Counter()
        """Requests each servo was asked to answer, by (servo id, instruction): tests wait on these."""
        self.unanswered: collections.Counter[int] = collections.Counter()
        """Requests to a servo that had vanished, by servo id."""
        self._lock = threading.RLock()
        self._buffer = bytearray()
        self._rng = random.Random(seed)
        self._drop: dict[int | None, int] = {}
        self._corrupt: dict[int | None, int] = {}
        self._late: dict[int | None, list[float]] = {}
        self._short: dict[int | None, int] = {}
        self.drop_rate = 0.0
        self.corrupt_rate = 0.0
        self.short_rate = 0.0
        self._server = PtyServer(self._on_bytes, link=link, name="dynamixel-emulator")
        self._on_torque = on_torque
        self._torque = {i: s.torque for i, s in self.servos.items()}

    def servo(self, servo_id: int) -> EmulatedServo:
        return self.servos[servo_id]

    def goals(self, servo_id: int, inst: int | None = None) -> list[LoggedWrite]:
        """Goal positions written to one servo, optionally only those a given instruction carried."""
        with self._lock:
            return [g for g in self.goal_log if g.servo_id == servo_id and inst in (None, g.inst)]

    # ------------------------------------------------------------- faults
    def drop_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        """Swallow the next ``count`` replies (of one servo, or of any)."""
        with self._lock:
            self._drop[servo_id] = self._drop.get(servo_id, 0) + count

    def corrupt_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        with self._lock:
            self._corrupt[servo_id] = self._corrupt.get(servo_id, 0) + count

    def delay_replies(self, seconds: float, count: int = 1, servo_id: int | None = None) -> None:
        """Hold the next ``count`` replies ``seconds`` longer: the host times out and the late
        reply arrives while it waits for the answer to its next request (a stale reply)."""
        with self._lock:
            self._late.setdefault(servo_id, []).extend([seconds] * count)

    def short_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        """Cut the last data byte off the next ``count`` replies that carry data (CRC kept valid)."""
        with self._lock:
            self._short[servo_id] = self._short.get(servo_id, 0) + count

    def hardware_error(self, servo_id: int, fault: str) -> None:
        with self._lock:
            self.servos[servo_id].set_error(fault)
            self._torque_changed(f"hardware error: {fault}")

    def vanish(self, servo_id: int, seconds: float | None = None) -> None:
        """The servo stops answering (cable pulled); back after ``seconds`` if given."""
        self.servos[servo_id].alive = False
        if seconds is not None:
            self._server.after(seconds, lambda: self.reappear(servo_id))

    def reappear(self, servo_id: int) -> None:
        servo = self.servos[servo_id]
        with self._lock:
            servo.alive = True
            servo.reboot()  # power came back: RAM state is lost, torque off
            self._torque_changed("power came back")

    def unplug(self, seconds: float | None = None) -> None:
        """The USB adapter disappears; with ``seconds`` it comes back under the same link."""
        self._server.unplug(seconds)

    def replug(self) -> None:
        self._server.replug()

    def schedule(self, fault: Fault) -> None:
        """Apply ``fault`` ``fault.at`` seconds from now; a fault this bus cannot have is a
        ``UserError`` here, not an exception in the timer thread later."""
        self.check_fault(fault)
        self._server.after(fault.at, lambda: fault.apply(self))

    def check_fault(self, fault: Fault) -> None:
        if fault.kind not in SERVO_FAULTS:
            return
        servo_id = fault.servo_id
        if servo_id not in self.servos:
            ids = ", ".join(map(str, sorted(self.servos))) or "none"
            raise UserError(f"--fault {fault}: no servo {servo_id} on the emulated bus (ids: {ids})")
        errors = self.servos[servo_id].table.error_bits.values()
        if fault.kind != "vanish" and fault.kind not in errors:
            model = self.servos[servo_id].model.name
            raise UserError(f"--fault {fault}: a {model} has no {fault.kind} error (it has: {', '.join(errors)})")

    # ------------------------------------------------------------- protocol
    def _on_bytes(self, data: bytes) -> None:
        arrived = time.perf_counter()
        with self._lock:
            self._buffer.extend(data)
            replies: list[tuple[int, bytes]] = []
            request_bytes = 0
            while (packet := dp.parse(self._buffer)) is not None:
                self.counters["packets"] += 1
                request_bytes += 10 + len(packet.params)
                replies.extend(self._handle(packet))
            self._torque_changed("commanded")
            out = [(self._delay_us(sid) * 1e-6 + self._lateness(sid), self._mangle(sid, raw)) for sid, raw in replies]
        due = arrived + self._wire_s(request_bytes)
        for delay, raw in out:
            due += delay  # Return_Delay_Time (and an injected lateness): the servo waits before it answers
            if delay > 0.001:
                time.sleep(max(0.0, due - time.perf_counter()))
            if raw is None:
                continue
            due += self._wire_s(len(raw))
            self._wait_until(due)
            self._server.send(raw)
            self.counters["replies"] += 1

    def _torque_changed(self, why: str) -> None:
        """Tell ``on_torque`` about every servo whose torque differs from what it last heard."""
        for servo_id, servo in self.servos.items():
            on = servo.torque
            if on != self._torque[servo_id]:
                self._torque[servo_id] = on
                if self._on_torque is not None:
                    self._on_torque(servo_id, on, why)

    def _delay_us(self, servo_id: int) -> float:
        servo = self.servos.get(servo_id)
        return 2.0 * servo.get("Return_Delay_Time") if servo is not None else 0.0

    def _lateness(self, servo_id: int) -> float:
        for key in (servo_id, None):
            if self._late.get(key):
                return self._late[key].pop(0)
        return 0.0

    def _wire_s(self, nbytes: int) -> float:
        """Time ``nbytes`` take on the emulated wire (10 bits per byte; 0 if not emulated)."""
        return nbytes * 10.0 / self.baudrate if self.baudrate else 0.0

    def _wait_until(self, due: float) -> None:
        """Hold a reply until it would have finished on a real bus."""
        if not self.baudrate:
            return
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)

    def _mangle(self, servo_id: int, raw: bytes) -> bytes | None:
        for key in (servo_id, None):
            if self._drop.get(key, 0) > 0:
                self._drop[key] -= 1
                self.counters["dropped"] += 1
                return None
        if self.drop_rate and self._rng.random() < self.drop_rate:
            self.counters["dropped"] += 1
            return None
        corrupt = self.corrupt_rate and self._rng.random() < self.corrupt_rate
        for key in (servo_id, None):
            if not corrupt and self._corrupt.get(key, 0) > 0:
                self._corrupt[key] -= 1
                corrupt = True
        if corrupt:
            self.counters["corrupted"] += 1
            return raw[:-2] + bytes([raw[-2] ^ 0x5A, raw[-1]])
        return self._shorten(servo_id, raw)

    def _shorten(self, servo_id: int, raw: bytes) -> bytes:
        body = dp.unstuff(raw[7:-2])  # STATUS, error, data
        if len(body) <= 2:  # no data to cut
            return raw
        short = self.short_rate and self._rng.random() < self.short_rate
        for key in (servo_id, None):
            if not short and self._short.get(key, 0) > 0:
                self._short[key] -= 1
                short = True
        if not short:
            return raw
        self.counters["shortened"] += 1
        return dp.status(raw[4], body[1], body[2:-1])

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
