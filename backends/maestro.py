"""Backend ``maestro``: hobby servos behind a Pololu Maestro USB servo controller (pyserial).

Every frame is one serial write of set-target commands (quarter-microseconds). The health poll
asks for the controller's error bits and every channel's position in one write. Hobby servos
report nothing back, so "torque off" is a target of 0, which stops the pulses. The safety loop
(limits, watchdog, ease to neutral) is ``servo_base.ServoBackend``.

Options (``backends.maestro`` in the robot profile)::

    port: /dev/ttyACM0   baudrate: 115200   device: null (compact protocol; a number = Pololu protocol)
    timeout_s: 0.05      read_rate: 5       watchdog_s: 0.5   ease_s: 1.0
    joints:
      neck_pan: {channel: 0, zero_us: 1500, us_per_unit: 600, min_us: 650, max_us: 2350,
                 speed: 0, acceleration: 0}

Pulse width = ``zero_us + us_per_unit * value``, kept inside ``[min_us, max_us]``; a negative
``us_per_unit`` reverses the servo.
"""

from __future__ import annotations

import termios
import time
from typing import Any

import numpy as np
import serial

from convodrive.backends.servo import maestro_protocol as mp
from convodrive.backends.servo.safety import RawMap
from convodrive.backends.servo.servo_base import PortLost, ServoBackend, open_error
from convodrive.motion.targets import TargetSpec
from convodrive.plumbing.errors import UserError

SERIAL_ERRORS = (serial.SerialException, OSError, termios.error, TypeError)
MIN_US, MAX_US = 64.0, 4000.0


class MaestroBackend(ServoBackend):
    name = "maestro"
    description = "Hobby servos on a Pololu Maestro USB servo controller (compact protocol, pyserial)"
    realtime = True
    default_profile = "servo_head"
    requires = ("serial",)
    extra = "hardware"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        super().__init__(options)
        self.serial: serial.Serial | None = None
        self.channels: list[int] = []
        self._limits: dict[str, tuple[int, int]] = {}
        self._device = self.options.get("device")
        self._status: dict[str, dict[str, Any]] = {}
        self._controller_errors: list[str] = []
        self._last_seen: float | None = None
        self._timeouts = 0

    # ---------------------------------------------------------------- calibration
    def _hw_calibration(self, spec: TargetSpec) -> RawMap:
        joints = self.options.get("joints")
        if joints is None:
            joints = {name: {"channel": i} for i, name in enumerate(spec.names)}
        if not isinstance(joints, dict):
            raise UserError("backends.maestro.joints: expected a mapping of joint name to channel settings")
        unknown = sorted(set(joints) - set(spec.names))
        if unknown:
            raise UserError(f"backends.maestro.joints: {', '.join(unknown)} not in profile {spec.name}")
        zero, scale, low, high = [], [], [], []
        for name in (n for n in spec.names if n in joints):
            key = f"backends.maestro.joints.{name}"
            j = joints[name] or {}
            try:
                channel = int(j["channel"])
                z, s = float(j.get("zero_us", 1500.0)), float(j.get("us_per_unit", 600.0))
                lo, hi = float(j.get("min_us", 1000.0)), float(j.get("max_us", 2000.0))
                speed, accel = int(j.get("speed", 0)), int(j.get("acceleration", 0))
            except (KeyError, TypeError, ValueError) as exc:
                raise UserError(f"{key}: bad channel settings ({type(exc).__name__}: {exc})") from None
            if not 0 <= channel <= 23 or channel in self.channels:
                raise UserError(f"{key}.channel: {channel} is not a free channel 0..23")
            if s == 0 or not MIN_US <= lo <= hi <= MAX_US:
                raise UserError(f"{key}: need us_per_unit != 0 and {MIN_US:g} <= min_us <= max_us <= {MAX_US:g}")
            if not (0 <= speed < 1 << 14 and 0 <= accel <= 255):
                raise UserError(f"{key}: speed 0..16383 and acceleration 0..255")
            self.channels.append(channel)
            self._limits[name] = (speed, accel)
            zero.append(4 * z), scale.append(4 * s), low.append(np.ceil(4 * lo)), high.append(np.floor(4 * hi))
        if not self.channels:
            raise UserError("backends.maestro.joints: no joint is mapped to a channel")
        self.names = [n for n in spec.names if n in joints]
        return RawMap(np.array(zero), np.array(scale), np.array(low), np.array(high))

    # ---------------------------------------------------------------- serial
    def _cmd(self, command: bytes) -> bytes:
        return mp.pololu(int(self._device), command) if self._device is not None else command

    def _io(self, request: bytes, reply_len: int = 0) -> bytes:
        """Write a request and read exactly ``reply_len`` bytes (fewer on timeout)."""
        if self.serial is None:
            raise PortLost(f"{self.options['port']}: not connected")
        try:
            if reply_len:
                self.serial.reset_input_buffer()
            self.serial.write(request)
            return self.serial.read(reply_len) if reply_len else b""
        except SERIAL_ERRORS as exc:
            self._drop_port()
            raise PortLost(f"{self.options['port']}: {exc}") from None

    def _drop_port(self) -> None:
        if self.serial is not None:
            try:
                self.serial.close()
            except SERIAL_ERRORS:
                pass
        self.serial = None

    def _connect(self) -> bool:
        """Open the port and check the controller answers; False if it does not."""
        port = str(self.options["port"])
        try:
            self.serial = serial.Serial(
                port,
                int(self.options.get("baudrate", 115200)),
                timeout=float(self.options.get("timeout_s", 0.05)),
                write_timeout=0.5,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise open_error(port, exc) from None
        if len(self._io(self._cmd(mp.get_errors()), 2)) != 2:
            self._drop_port()
            return False
        setup = b"".join(
            self._cmd(mp.set_speed(c, self._limits[n][0])) + self._cmd(mp.set_acceleration(c, self._limits[n][1]))
            for n, c in zip(self.names, self.channels)
        )
        self._io(setup)
        return True

    def _hw_open(self) -> None:
        if not self._connect():
            raise UserError(f"{self.options['port']}: no Maestro answers (no reply to get-errors)")

    def _positions(self) -> np.ndarray:
        """Positions in quarter-microseconds (NaN where the channel is off or did not answer)."""
        request = b"".join(self._cmd(mp.get_position(c)) for c in self.channels)
        reply = self._io(request, 2 * len(self.channels))
        out = np.full(len(self.channels), np.nan)
        for i in range(len(reply) // 2):
            value = reply[2 * i] | (reply[2 * i + 1] << 8)
            out[i] = value if value else np.nan
        if len(reply) < 2 * len(self.channels):
            self._timeouts += 1
        return out

    def _hw_present(self) -> np.ndarray:
        return self._positions()

    def _hw_write(self, raw: np.ndarray) -> None:
        self._io(b"".join(self._cmd(mp.set_target(c, int(t))) for c, t in zip(self.channels, raw.tolist())))

    def _hw_poll(self) -> None:
        reply = self._io(self._cmd(mp.get_errors()), 2)
        if len(reply) != 2:
            self._timeouts += 1
            self._event("lost_replies", None, "no reply to get-errors")
            return
        self._last_seen = time.monotonic()
        errors = mp.decode_errors(reply[0] | (reply[1] << 8))  # reading clears them on the controller
        for name in errors:
            self._event(f"controller_{name}", None, "Maestro error bit")
        self._controller_errors = errors
        positions = self._positions()
        for name, pos in zip(self.names, positions):
            self._status[name] = {"position_us": None if np.isnan(pos) else pos / 4.0}

    def _hw_reconnect(self) -> bool:
        try:
            return self._connect()
        except (UserError, PortLost):
            self._drop_port()
            return False

    def _hw_connected(self) -> bool:
        return self.serial is not None

    def _hw_off(self) -> dict[str, bool]:
        self._io(b"".join(self._cmd(mp.set_target(c, 0)) for c in self.channels))
        request = b"".join(self._cmd(mp.get_position(c)) for c in self.channels)
        reply = self._io(request, 2 * len(self.channels))  # an off channel reads 0
        return {n: reply[2 * i : 2 * i + 2] == b"\x00\x00" for i, n in enumerate(self.names)}

    def _hw_close(self) -> None:
        self._drop_port()

    def _hw_health(self) -> dict[str, dict[str, Any]]:
        seen = None if self._last_seen is None else round(time.monotonic() - self._last_seen, 3)
        return {
            n: {
                "channel": c,
                "status": "ok",
                "last_seen_s": seen,
                "timeouts": self._timeouts,
                "faults": list(self._controller_errors),
                **self._status.get(n, {}),
            }
            for n, c in zip(self.names, self.channels)
        }
