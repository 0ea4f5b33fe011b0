"""What the emulated Dynamixel and Feetech buses share: a pty, reply timing, and injected faults.

A request's replies go out after its own time on the wire, each servo's Return_Delay_Time (plus
any injected lateness) and the reply's wire time at the emulated baud rate. Faults come through
the API or ``--fault`` (``emulator_faults``): lost, corrupt, short or late replies (queued for one
servo or any, or at a rate), a servo's fault bit, a servo that vanishes and comes back with its RAM
reset, a port that disappears. A protocol's emulator (``dynamixel_emulator``, ``feetech_emulator``)
parses and answers packets, and says how its packets are corrupted and shortened.
"""

from __future__ import annotations

import collections
import dataclasses
import random
import threading
import time
from collections.abc import Callable
from typing import Any

from convodrive.backends.servo.emulator_faults import SERVO_FAULTS, Fault
from convodrive.backends.servo.pty_server import PtyDevice, PtyServer
from convodrive.plumbing.errors import UserError

Clock = Callable[[], float]
REPLY_FAULTS = ("drop", "corrupt", "short")


@dataclasses.dataclass
class LoggedWrite:
    """One accepted goal or torque write, as the servo saw it (emulator clock)."""

    time: float
    servo_id: int
    value: int
    inst: int = 3
    """The instruction that carried it (WRITE, 3 in both protocols; SYNC_WRITE, BULK_WRITE, ACTION)."""
    packet: int = 0
    """The ordinal of the packet that carried it: writes of one SYNC_WRITE share it."""

    @property
    def tick(self) -> int:
        """For goal positions: the goal in ticks."""
        return self.value


class BusEmulator(PtyDevice):
    """Servos on one emulated bus. A context manager; ``port`` is the path to open."""

    def __init__(
        self,
        servos: dict[int, Any],
        *,
        baudrate: int,
        link: str | None,
        clock: Clock,
        seed: int,
        on_torque: Callable[[int, bool, str], None] | None,
        counters: tuple[str, ...],
        name: str,
    ) -> None:
        """``on_torque(servo_id, on, why)`` hears every change of a servo's torque, whoever made it."""
        self.clock = clock
        self.baudrate = baudrate
        self.servos = servos
        self.goal_log: list[LoggedWrite] = []
        self.torque_log: list[LoggedWrite] = []  # every accepted Torque_Enable write
        self.sync_read_times: list[float] = []
        """When each SYNC_READ came in (emulator clock): a driver's reads, against its goals."""
        self.counters = collections.Counter({k: 0 for k in ("packets", "replies", "dropped", "corrupted", "shortened")})
        self.counters.update({k: 0 for k in counters})
        self.unanswered: collections.Counter[int] = collections.Counter()
        """Requests to a servo that had vanished, by servo id."""
        self.drop_rate = self.corrupt_rate = self.short_rate = 0.0
        self._lock = threading.RLock()
        self._buffer = bytearray()
        self._rng = random.Random(seed)
        self._pending: dict[str, dict[int | None, int]] = {kind: {} for kind in REPLY_FAULTS}
        self._late: dict[int | None, list[float]] = {}
        self._server = PtyServer(self._on_bytes, link=link, name=name)
        self._on_torque = on_torque
        self._torque = {i: s.torque for i, s in self.servos.items()}

    # ------------------------------------------------------------- what a protocol gives
    def _parse(self, buffer: bytearray) -> Any:
        """The next whole packet taken off ``buffer``, or None."""
        raise NotImplementedError

    def _handle(self, packet: Any) -> list[tuple[int, bytes]]:
        """The replies to one packet: (servo id, status packet)."""
        raise NotImplementedError

    def _corrupted(self, raw: bytes) -> bytes:
        """``raw`` with a checksum that fails."""
        raise NotImplementedError

    def _shortened(self, raw: bytes) -> bytes | None:
        """``raw`` one data byte short with a valid checksum; None when it carries no data."""
        raise NotImplementedError

    def servo(self, servo_id: int) -> Any:
        return self.servos[servo_id]

    # ------------------------------------------------------------- faults
    def drop_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        """Swallow the next ``count`` replies (of one servo, or of any)."""
        self._queue("drop", count, servo_id)

    def corrupt_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        self._queue("corrupt", count, servo_id)

    def short_replies(self, count: int = 1, servo_id: int | None = None) -> None:
        """Cut the last data byte off the next ``count`` replies that carry data (checksum kept valid)."""
        self._queue("short", count, servo_id)

    def delay_replies(self, seconds: float, count: int = 1, servo_id: int | None = None) -> None:
        """Hold the next ``count`` replies ``seconds`` longer: the host times out and the late
        reply arrives while it waits for the answer to its next request (a stale reply)."""
        with self._lock:
            self._late.setdefault(servo_id, []).extend([seconds] * count)

    def _queue(self, kind: str, count: int, servo_id: int | None) -> None:
        with self._lock:
            self._pending[kind][servo_id] = self._pending[kind].get(servo_id, 0) + count

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
        with self._lock:
            servo = self.servos[servo_id]
            servo.alive = True
            servo.power_cycle()  # power came back: RAM state is lost, torque off
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
        if fault.servo_id not in self.servos:
            ids = ", ".join(map(str, sorted(self.servos))) or "none"
            raise UserError(f"--fault {fault}: no servo {fault.servo_id} on the emulated bus (ids: {ids})")
        servo = self.servos[fault.servo_id]
        errors = servo.table.error_bits.values()
        if fault.kind != "vanish" and fault.kind not in errors:
            raise UserError(
                f"--fault {fault}: a {servo.model.name} has no {fault.kind} error (it has: {', '.join(errors)})"
            )

    # ------------------------------------------------------------- wire
    def _on_bytes(self, data: bytes) -> None:
        arrived = time.perf_counter()
        with self._lock:
            self._buffer.extend(data)
            replies: list[tuple[int, bytes]] = []
            request_bytes = 0
            while (packet := self._parse(self._buffer)) is not None:
                self.counters["packets"] += 1
                request_bytes += packet.size
                replies.extend(self._handle(packet))
            self._torque_changed("commanded")
            out = [(self._delay_s(sid) + self._lateness(sid), self._mangle(sid, raw)) for sid, raw in replies]
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

    def _delay_s(self, servo_id: int) -> float:
        servo = self.servos.get(servo_id)
        return 2e-6 * servo.get("Return_Delay_Time") if servo is not None else 0.0  # 2 us units

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
            return self._corrupted(raw)
        short = self._shortened(raw)
        if short is not None and self._take("short", servo_id, self.short_rate):
            self.counters["shortened"] += 1
            return short
        return raw
