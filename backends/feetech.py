"""Backend ``feetech``: a servo head on Feetech STS/SCS serial-bus servos (feetech-servo-sdk).

Every frame becomes one SYNC_WRITE of goal steps; the supervisor's health poll is one SYNC_READ
(STS; SCS servos one READ each) of present position, load, voltage and temperature, whose status
packets also carry each servo's fault bits. A servo that stops answering is retried with back-off
and re-initialised (limits, speed, torque) when it answers again. The safety loop itself (limits,
watchdog, ease to neutral, torque off) is ``servo_base.ServoBackend``, as for the Dynamixel head.

Options: ``FeetechOptions`` (``convodrive plugins feetech`` lists them), usually in the robot
profile's ``backends.feetech``, one ``joints`` entry per servo, the Dynamixel head's format::

    joints:
      neck_pan: {id: 1, zero_tick: 2048, direction: 1, min_tick: 1135, max_tick: 2961, velocity: 2000}

``ticks_per_unit`` defaults to steps per radian; joints missing from ``joints`` are not driven;
without ``joints`` the spec's joints take ids 1..N with the model's centre step as zero.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from convodrive.backends.servo import feetech_table as ft
from convodrive.backends.servo.feetech_bus import FeetechBus, Motor
from convodrive.backends.servo.feetech_options import FeetechJoint, FeetechOptions
from convodrive.backends.servo.safety import RawMap
from convodrive.backends.servo.serial_port import PortLost
from convodrive.backends.servo.servo_base import ServoBackend
from convodrive.motion.targets import TargetSpec
from convodrive.plugins.options import PluginOptions
from convodrive.plumbing.errors import UserError

HEALTH_REGISTERS = ["Present_Position", "Present_Load", "Present_Voltage", "Present_Temperature"]


def bus_motors(options: FeetechOptions, names: list[str] | None = None) -> list[Motor]:
    """The servos of ``options.joints`` (only ``names`` when given), each with its model."""
    default = ft.model(options.model)
    return [
        Motor(name, j.id, ft.model(j.model) if j.model else default)
        for name, j in (options.joints or {}).items()
        if names is None or name in names
    ]


def make_bus(options: FeetechOptions, motors: list[Motor], port: str | None = None) -> FeetechBus:
    """A bus (not yet connected) for ``motors`` at the options' speed and timing."""
    return FeetechBus(
        port or options.port, motors, baudrate=options.baudrate, retries=options.retries, latency_ms=options.latency_ms
    )


class FeetechBackend(ServoBackend):
    name = "feetech"
    description = "Feetech STS/SCS serial-bus servo head (STS3215, SCS0009, ...) over feetech-servo-sdk"
    realtime = True
    hardware = True
    may_run_in_process = True
    default_profile = "servo_head"
    requires = ("scservo_sdk", "dynamixel_sdk", "serial")
    extra = "hardware"
    Options = FeetechOptions
    options: FeetechOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.bus: FeetechBus | None = None
        self._motors: list[Motor] = []
        self._motion: dict[str, tuple[int, int]] = {}
        self._limits: dict[str, tuple[int, int]] = {}
        self._return_delay = self.options.return_delay_us // 2  # 2 us units; factory 250 (500 us)

    # ---------------------------------------------------------------- calibration
    def _hw_calibration(self, spec: TargetSpec) -> RawMap:
        joints = self.options.joints
        if joints is None:
            joints = {name: FeetechJoint(id=i + 1) for i, name in enumerate(spec.names)}
        unknown = sorted(set(joints) - set(spec.names))
        if unknown:
            raise UserError(
                f"backends.feetech.joints: {', '.join(unknown)} not in profile {spec.name} "
                f"(joints: {', '.join(spec.names)})"
            )
        default_model = ft.model(self.options.model)
        zero, scale, low, high = [], [], [], []
        for name in (n for n in spec.names if n in joints):
            motor, z, s, lo, hi = self._joint(spec, name, joints[name], default_model)
            self._motors.append(motor)
            zero.append(z), scale.append(s), low.append(lo), high.append(hi)
        if not self._motors:
            raise UserError("backends.feetech.joints: no joint is mapped to a servo")
        self.names = [m.name for m in self._motors]
        return RawMap(np.array(zero), np.array(scale), np.array(low, float), np.array(high, float))

    def _joint(
        self, spec: TargetSpec, name: str, j: FeetechJoint, default: ft.Model
    ) -> tuple[Motor, float, float, int, int]:
        """Raw map of one joint; only what depends on the servo's model and the profile's limits is checked here."""
        key = f"backends.feetech.joints.{name}"
        i = spec.index[name]
        model = ft.model(j.model) if j.model else default
        table = model.table
        if j.ticks_per_unit is None and spec.units[i] != "rad":
            raise UserError(f"{key}: joint is in {spec.units[i]}, give ticks_per_unit")
        s = math.copysign(j.ticks_per_unit or 1.0 / table.rad_per_tick, j.direction)
        z = table.center_tick if j.zero_tick is None else j.zero_tick
        ends = sorted((z + s * spec.lower[i], z + s * spec.upper[i]))
        lo = max(0, math.floor(ends[0])) if j.min_tick is None else j.min_tick
        hi = min(table.max_tick, math.ceil(ends[1])) if j.max_tick is None else j.max_tick
        if not 0 <= lo <= hi <= table.max_tick:
            raise UserError(f"{key}: need 0 <= min_tick <= max_tick <= {table.max_tick} ({model.name})")
        self._motion[name] = (
            self.options.velocity if j.velocity is None else j.velocity,
            self.options.acceleration if j.acceleration is None else j.acceleration,
        )
        self._limits[name] = (lo, hi)
        return Motor(name, j.id, model), z, s, lo, hi

    # ---------------------------------------------------------------- bus
    def _hw_open(self) -> None:
        self.bus = make_bus(self.options, self._motors)
        self.bus.connect()
        answering = [m.name for m in self._motors if self._check_model(m)]
        if not answering:
            self.bus.disconnect()
            ids = ", ".join(str(m.id) for m in self._motors)
            raise UserError(f"{self.options.port}: no Feetech servo answers (ids {ids} at {self.bus.baudrate} baud)")
        for name in self.names:
            if name not in answering:
                self._event("servo_lost", name, "no answer at open")
        self._setup(answering)

    def _check_model(self, motor: Motor) -> bool:
        assert self.bus is not None
        found = self.bus.ping(motor.id)
        if found is None:
            return False
        if found != motor.model.name:
            self.bus.disconnect()
            raise UserError(
                f"backends.feetech.joints.{motor.name}: servo {motor.id} is {found}, the profile says {motor.model.name}"
            )
        return True

    def _setup(self, names: list[str]) -> None:
        """EEPROM (position limits, return delay; unlocked only if changed), speed, goal = present, torque on."""
        bus = self.bus
        assert bus is not None
        for name in names:
            lo, hi = self._limits[name]
            eeprom = {"Min_Position_Limit": lo, "Max_Position_Limit": hi, "Return_Delay_Time": self._return_delay}
            if any(bus.read(reg, name) != value for reg, value in eeprom.items()):
                bus.write("Lock", name, 0)
                for reg, value in eeprom.items():
                    bus.write(reg, name, value)
                bus.write("Lock", name, 1)
            velocity, acceleration = self._motion[name]
            bus.write("Goal_Velocity", name, velocity)
            bus.write("Acceleration", name, acceleration)
            present = bus.read("Present_Position", name)
            if present is not None:
                bus.write("Goal_Position", name, int(np.clip(present, lo, hi)))
            bus.write("Torque_Enable", name, 1)

    def _hw_present(self) -> np.ndarray:
        assert self.bus is not None
        values = [self.bus.read("Present_Position", n) for n in self.names]
        return np.array([np.nan if v is None else v for v in values], dtype=float)

    def _hw_write(self, raw: np.ndarray) -> None:
        assert self.bus is not None
        self.bus.sync_write("Goal_Position", dict(zip(self.names, raw.tolist())))

    def _hw_poll(self) -> None:
        bus = self.bus
        assert bus is not None
        lost_before = {n for n in self.names if bus.health[n].lost}
        data = bus.sync_read(HEALTH_REGISTERS)
        for name, regs in data.items():
            h = bus.health[name]
            h.position, h.temperature = regs["Present_Position"], regs["Present_Temperature"]
            h.voltage = regs["Present_Voltage"] / 10.0
        for name, fault, error in bus.take_new_faults():
            self._event(fault, name, f"status error byte 0x{error:02x}")
        for name in self.names:
            h = bus.health[name]
            if h.lost and name not in lost_before:
                self._event("servo_lost", name, f"no status packet after {bus.retries} retries")
            if h.timeouts:
                self._add_fault("lost_replies", name, f"{h.timeouts} status read(s) timed out")
            if h.corrupt:
                self._add_fault("bad_checksum", name, f"{h.corrupt} status packet(s) failed their checksum")
            if h.short:
                self._add_fault("short_replies", name, f"{h.short} status packet(s) shorter than the data asked for")
        recovered = sorted(lost_before & set(data))
        if recovered:
            self._event("servo_recovered", ",".join(recovered), "answering again; re-initialised", fault=False)
            with self._lock:  # not between a frame's goals
                self._setup(recovered)

    def _hw_reconnect(self) -> bool:
        bus = self.bus
        if bus is None:
            return False
        try:
            bus.connect()
            answering = [n for n in self.names if bus.ping(bus.motors[n].id)]
        except (UserError, PortLost):
            bus.disconnect()
            return False
        if not answering:
            bus.disconnect()
            return False
        self._setup(answering)
        return True

    def _hw_connected(self) -> bool:
        return self.bus is not None and self.bus.connected

    def _hw_off(self) -> dict[str, bool]:
        assert self.bus is not None
        return {n: self.bus.write("Torque_Enable", n, 0) for n in self.names}

    def _hw_close(self) -> None:
        if self.bus is not None:
            self.bus.disconnect()

    def _hw_bus(self) -> dict[str, Any]:
        return {"group_read_timeouts": self.bus.group_timeouts if self.bus is not None else 0}

    def _hw_health(self) -> dict[str, dict[str, Any]]:
        if self.bus is None:
            return {}
        return {n: self.bus.health[n].as_dict() for n in self.names}
