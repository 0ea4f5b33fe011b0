"""A Pololu Maestro servo controller on a pseudo-terminal, for tests and for users without one.

It decodes the compact and the Pololu protocol byte by byte (set target, set multiple targets,
speed, acceleration, get position, get moving state, get errors, go home), moves each channel's
position toward its target under the speed and acceleration limits, raises the serial-protocol
error bit on a malformed command, and injects faults on demand: dropped replies, error bits, a
port that disappears.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable

from convodrive.backends.servo import maestro_protocol as mp
from convodrive.backends.servo.pty_server import PtyDevice, PtyServer
from convodrive.plumbing.errors import UserError

# Command byte -> number of data bytes that follow it (SET_MULTIPLE_TARGETS is variable).
DATA_BYTES = {
    mp.SET_TARGET: 3,
    mp.SET_SPEED: 3,
    mp.SET_ACCELERATION: 3,
    mp.GET_POSITION: 1,
    mp.GET_MOVING_STATE: 0,
    mp.GET_ERRORS: 0,
    mp.GO_HOME: 0,
}


@dataclasses.dataclass
class Channel:
    target: int = 0
    position: float = 0.0
    velocity: float = 0.0
    speed: int = 0
    acceleration: int = 0

    def step(self, dt: float) -> None:
        if self.target == 0:
            self.position, self.velocity = 0.0, 0.0  # pulses off
            return
        if self.position == 0.0 or (self.speed == 0 and self.acceleration == 0):
            self.position, self.velocity = float(self.target), 0.0
            return
        vmax = self.speed * 100.0 if self.speed else float("inf")  # quarter-us per second
        amax = self.acceleration * 1250.0 if self.acceleration else float("inf")
        delta = self.target - self.position
        want = max(-vmax, min(vmax, delta / dt if dt > 0 else 0.0))
        self.velocity = max(self.velocity - amax * dt, min(self.velocity + amax * dt, want))
        move = self.velocity * dt
        self.position = float(self.target) if abs(move) >= abs(delta) else self.position + move


@dataclasses.dataclass
class TargetWrite:
    time: float
    channel: int
    target: int


class MaestroEmulator(PtyDevice):
    """A Mini Maestro with ``channels`` servo channels. A context manager; ``port`` is the path."""

    def __init__(
        self,
        channels: int = 12,
        *,
        device: int = 12,
        link: str | None = None,
        clock: Callable[[], float] = time.monotonic,
        on_pulses: Callable[[int, bool], None] | None = None,
    ) -> None:
        """``on_pulses(channel, on)`` hears a channel's pulses start or stop (a hobby servo's torque)."""
        self.channels = [Channel() for _ in range(channels)]
        self._on_pulses = on_pulses
        self.device = device
        self.clock = clock
        self.errors = 0
        self.target_log: list[TargetWrite] = []
        self.counters = {"commands": 0, "replies": 0, "dropped": 0}
        self._buffer = bytearray()
        self._lock = threading.RLock()
        self._drop = 0
        self._last = clock()
        self._server = PtyServer(self._on_bytes, link=link, name="maestro-emulator")

    def targets(self, channel: int) -> list[TargetWrite]:
        with self._lock:
            return [t for t in self.target_log if t.channel == channel]

    # ------------------------------------------------------------- faults
    def drop_replies(self, count: int = 1) -> None:
        with self._lock:
            self._drop += count

    def raise_error(self, name: str) -> None:
        bits = {v: k for k, v in mp.ERROR_BITS.items()}
        if name not in bits:
            raise UserError(f"unknown Maestro error {name!r} (known: {', '.join(bits)})")
        with self._lock:
            self.errors |= 1 << bits[name]

    def unplug(self, seconds: float | None = None) -> None:
        self._server.unplug(seconds)

    def after(self, seconds: float, action: Callable[[], None]) -> None:
        """Run a fault later (command-line schedules)."""
        self._server.after(seconds, action)

    # ------------------------------------------------------------- protocol
    def _update(self) -> None:
        now = self.clock()
        dt, self._last = max(0.0, now - self._last), now
        for ch in self.channels:
            ch.step(dt)

    def _on_bytes(self, data: bytes) -> None:
        with self._lock:
            self._buffer.extend(data)
            self._update()
            replies = bytearray()
            while (command := self._take()) is not None:
                self.counters["commands"] += 1
                reply = self._execute(*command)
                if reply:
                    if self._drop:
                        self._drop -= 1
                        self.counters["dropped"] += 1
                    else:
                        replies += reply
                        self.counters["replies"] += 1
        if replies:
            self._server.send(bytes(replies))

    def _take(self) -> tuple[int, bytes] | None:
        """One complete command off the buffer (compact or Pololu), or None if incomplete."""
        buf = self._buffer
        while buf and buf[0] < 0x80:  # a data byte where a command should start
            del buf[0]
            self.errors |= 1 << 4
        if not buf:
            return None
        if buf[0] == 0xAA:
            if len(buf) < 3:
                return None
            if buf[1] != self.device:  # for another device on the line: skip its command byte
                command = buf[2] | 0x80
                need = self._need(command, buf, 3)
                if need is None:
                    return None
                del buf[: 3 + need]
                return self._take()
            command, start = buf[2] | 0x80, 3
        else:
            command, start = buf[0], 1
        need = self._need(command, buf, start)
        if need is None:
            return None
        args = bytes(buf[start : start + need])
        del buf[: start + need]
        if any(b >= 0x80 for b in args):
            self.errors |= 1 << 4
            return self._take()
        return command, args

    def _need(self, command: int, buf: bytearray, start: int) -> int | None:
        if command == mp.SET_MULTIPLE_TARGETS:
            if len(buf) < start + 1:
                return None
            need = 2 + 2 * buf[start]
        else:
            need = DATA_BYTES.get(command, 0)
        return need if len(buf) >= start + need else None

    def _execute(self, command: int, args: bytes) -> bytes:
        if command == mp.SET_MULTIPLE_TARGETS:
            count, first = args[0], args[1]
            for k in range(count):
                self._set(first + k, args[2 + 2 * k] | (args[3 + 2 * k] << 7), "target")
            return b""
        if command in (mp.SET_TARGET, mp.SET_SPEED, mp.SET_ACCELERATION):
            field = {mp.SET_TARGET: "target", mp.SET_SPEED: "speed", mp.SET_ACCELERATION: "acceleration"}[command]
            self._set(args[0], args[1] | (args[2] << 7), field)
            return b""
        if command == mp.GET_POSITION:
            if args[0] >= len(self.channels):
                self.errors |= 1 << 4
                return b""
            value = int(round(self.channels[args[0]].position))
            return bytes([value & 0xFF, value >> 8])
        if command == mp.GET_MOVING_STATE:
            return bytes([int(any(round(c.position) != c.target for c in self.channels))])
        if command == mp.GET_ERRORS:
            errors, self.errors = self.errors, 0
            return bytes([errors & 0xFF, errors >> 8])
        if command == mp.GO_HOME:
            for i in range(len(self.channels)):
                self._set(i, 0, "target")
            return b""
        self.errors |= 1 << 4  # unknown command
        return b""

    def _set(self, channel: int, value: int, field: str) -> None:
        if channel >= len(self.channels):
            self.errors |= 1 << 4
            return
        ch = self.channels[channel]
        was_on = ch.target != 0
        setattr(ch, field, value)
        if field == "target" and was_on != (value != 0) and self._on_pulses is not None:
            self._on_pulses(channel, value != 0)
        if field == "target":
            if value == 0:
                ch.position, ch.velocity = 0.0, 0.0  # pulses stop at once
            elif ch.position == 0.0:
                ch.position = float(value)  # first pulse: the servo jumps there, as real ones do
            self.target_log.append(TargetWrite(self.clock(), channel, value))


def start_emulated_maestro(channels: int = 12, *, link: str | None = None) -> MaestroEmulator:
    """An emulated Maestro on a fresh pty, already serving (use as a context manager)."""
    return MaestroEmulator(channels, link=link).start()
