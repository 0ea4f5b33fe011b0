"""Backend ``maestro``: hobby servos behind a Pololu Maestro USB servo controller (pyserial).

Every frame is one serial write of set-target commands (quarter-microseconds). The health poll
asks for the controller's error bits and every channel's position in one write. Hobby servos
report nothing back, so "torque off" is a target of 0, which stops the pulses. The safety loop
(limits, watchdog, ease to neutral) is ``servo_base.ServoBackend``.

Options: ``MaestroOptions`` below (``convodrive plugins maestro`` lists them), usually in the
robot profile's ``backends.maestro``, one ``joints`` entry per channel::

    joints:
      neck_pan: {channel: 0, zero_us: 1500, us_per_unit: 600, min_us: 650, max_us: 2350}

Pulse width = ``zero_us + us_per_unit * value``, kept inside ``[min_us, max_us]``; a negative
``us_per_unit`` reverses the servo.
"""

from __future__ import annotations

import termios
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import serial

from convodrive.backends.servo import maestro_protocol as mp
from convodrive.backends.servo.safety import RawMap
from convodrive.backends.servo.serial_port import PortLost, open_error
from convodrive.backends.servo.servo_base import ServoBackend
from convodrive.backends.servo.servo_options import MaestroJoint, MaestroOptions
from convodrive.motion.targets import TargetSpec
from convodrive.plugins.options import PluginOptions
from convodrive.plumbing.errors import UserError

SERIAL_ERRORS = (serial.SerialException, OSError, termios.error, TypeError)


class MaestroBackend(ServoBackend):
    name = "maestro"
    description = "Hobby servos on a Pololu Maestro USB servo controller (compact protocol, pyserial)"
    realtime = True
    hardware = True
    neutral_tolerance_raw = 80.0  # quarter-microseconds: 20 us of pulse width, about 2 degrees
    may_run_in_process = True
    default_profile = "servo_head"
    requires = ("serial",)
    extra = "hardware"
    Options = MaestroOptions
    options: MaestroOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.serial: serial.Serial | None = None
        self.channels: list[int] = []
        self._limits: dict[str, tuple[int, int]] = {}
        self._device = self.options.device
        self._status: dict[str, dict[str, Any]] = {}
        self._controller_errors: list[str] = []
        self._last_seen: float | None = None
        self._timeouts = 0
        self._io_lock = threading.RLock()

    # ---------------------------------------------------------------- calibration
    def _hw_calibration(self, spec: TargetSpec) -> RawMap:
        joints = self.options.joints
        if joints is None:
            joints = {name: MaestroJoint(channel=i) for i, name in enumerate(spec.names)}
        unknown = sorted(set(joints) - set(spec.names))
        if unknown:
            raise UserError(f"backends.maestro.joints: {', '.join(unknown)} not in profile {spec.name}")
        zero, scale, low, high = [], [], [], []
        for name in (n for n in spec.names if n in joints):
            j = joints[name]
            self.channels.append(j.channel)
            self._limits[name] = (j.speed, j.acceleration)
            zero.append(4 * j.zero_us), scale.append(4 * j.us_per_unit)
            low.append(np.ceil(4 * j.min_us)), high.append(np.floor(4 * j.max_us))
        if not self.channels:
            raise UserError("backends.maestro.joints: no joint is mapped to a channel")
        self.names = [n for n in spec.names if n in joints]
        return RawMap(np.array(zero), np.array(scale), np.array(low), np.array(high))

    # ---------------------------------------------------------------- serial
    def _cmd(self, command: bytes) -> bytes:
        return mp.pololu(int(self._device), command) if self._device is not None else command

    def _io(self, request: bytes, reply_len: int = 0) -> bytes:
        """Write a request and read exactly ``reply_len`` bytes (fewer on timeout)."""
        with self._io_lock:  # one exchange at a time: the health poll runs beside the frames
            if self.serial is None:
                raise PortLost(f"{self.options.port}: not connected")
            try:
                if reply_len:
                    self.serial.reset_input_buffer()
                self.serial.write(request)
                return self.serial.read(reply_len) if reply_len else b""
            except SERIAL_ERRORS as exc:
                self._drop_port()
                raise PortLost(f"{self.options.port}: {exc}") from None

    def _drop_port(self) -> None:
        if self.serial is not None:
            try:
                self.serial.close()
            except SERIAL_ERRORS:
                pass
        self.serial = None

    def _connect(self) -> bool:
        """Open the port and check the controller answers; False if it does not."""
        port = self.options.port
        try:
            self.serial = serial.Serial(port, self.options.baudrate, timeout=self.options.timeout_s, write_timeout=0.5)
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
            raise UserError(f"{self.options.port}: no Maestro answers (no reply to get-errors)")
        self._check_channels()

    def _check_channels(self) -> None:
        """Ask each mapped channel for its position: a channel this Maestro lacks never answers
        (and raises the serial-protocol error bit), which must stop the run, not a servo."""
        for name, channel in zip(self.names, self.channels):
            if not any(len(self._io(self._cmd(mp.get_position(channel)), 2)) == 2 for _ in range(3)):
                self._drop_port()
                raise UserError(
                    f"backends.maestro.joints.{name}.channel: the Maestro on {self.options.port} does not answer "
                    f"for channel {channel} (does it have that many channels?)"
                )
        self._io(self._cmd(mp.get_errors()), 2)  # clear the error bits the probe may have raised

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
