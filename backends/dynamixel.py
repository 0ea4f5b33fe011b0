"""Backend ``dynamixel``: a servo head on Dynamixel Protocol 2.0 servos (dynamixel-sdk).

Every frame becomes one SYNC_WRITE of goal ticks; the supervisor's health poll is one SYNC_READ of
present position, input voltage and temperature, plus Hardware_Error_Status for servos whose
status packets raise the alert bit. A servo that stops answering is retried with back-off and
re-initialised (limits, profile, torque) when it answers again. The safety loop itself (limits,
watchdog, ease to neutral, torque off) is ``servo_base.ServoBackend``.

Options: ``DynamixelOptions`` below (``convodrive plugins dynamixel`` lists them), usually in the
robot profile's ``backends.dynamixel``, one ``joints`` entry per servo::

    joints:
      neck_pan: {id: 1, zero_tick: 2048, direction: 1, min_tick: 1135, max_tick: 2961,
                 profile_velocity: 150, profile_acceleration: 80}

``ticks_per_unit`` defaults to ticks per radian; joints missing from ``joints`` are not driven;
without ``joints`` the spec's joints take ids 1..N with the model's centre tick as zero. The servo
tools (``convodrive servo``) read the same declaration, so their flags and the backend agree.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from convodrive.backends.servo import dynamixel_table as dt
from convodrive.backends.servo.dynamixel_bus import DynamixelBus, Motor
from convodrive.backends.servo.safety import RawMap
from convodrive.backends.servo.serial_port import PortLost
from convodrive.backends.servo.servo_base import ServoBackend
from convodrive.backends.servo.servo_options import DynamixelJoint, DynamixelOptions
from convodrive.motion.targets import TargetSpec
from convodrive.plugins.options import PluginOptions
from convodrive.plumbing.errors import UserError

HEALTH_REGISTERS = ["Present_Position", "Present_Input_Voltage", "Present_Temperature"]
OPEN_PINGS = 3
"""Pings a servo gets at open before it counts as missing (and the run is refused)."""


def bus_motors(options: DynamixelOptions, names: list[str] | None = None) -> list[Motor]:
    """The servos of ``options.joints`` (only ``names`` when given), each with its model."""
    default = dt.model(options.model)
    joints = options.joints or {}
    return [
        Motor(name, j.id, dt.model(j.model) if j.model else default)
        for name, j in joints.items()
        if names is None or name in names
    ]


def make_bus(options: DynamixelOptions, motors: list[Motor], port: str | None = None) -> DynamixelBus:
    """A bus (not yet connected) for ``motors`` at the options' speed and timing."""
    return DynamixelBus(
        port or options.port,
        motors,
        baudrate=options.baudrate,
        retries=options.retries,
        latency_ms=options.latency_ms,
    )


class DynamixelBackend(ServoBackend):
    name = "dynamixel"
    description = "Dynamixel Protocol 2.0 servo head (XL330, XM430, XL-320, ...) over dynamixel-sdk"
    realtime = True
    hardware = True
    may_run_in_process = True
    default_profile = "servo_head"
    requires = ("dynamixel_sdk",)
    extra = "hardware"
    Options = DynamixelOptions
    options: DynamixelOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.bus: DynamixelBus | None = None
        self._motors: list[Motor] = []
        self._profile: dict[str, tuple[int, int]] = {}
        self._limits: dict[str, tuple[int, int]] = {}
        # Factory Return_Delay_Time is 250 (500 us per status packet); 0 keeps a 7-servo read short.
        self._return_delay = self.options.return_delay_us // 2

    # ---------------------------------------------------------------- calibration
    def _hw_calibration(self, spec: TargetSpec) -> RawMap:
        joints = self.options.joints
        if joints is None:
            joints = {name: DynamixelJoint(id=i + 1) for i, name in enumerate(spec.names)}
        unknown = sorted(set(joints) - set(spec.names))
        if unknown:
            raise UserError(
                f"backends.dynamixel.joints: {', '.join(unknown)} not in profile {spec.name} "
                f"(joints: {', '.join(spec.names)})"
            )
        default_model = dt.model(self.options.model)
        zero, scale, low, high = [], [], [], []
        for name in (n for n in spec.names if n in joints):
            motor, z, s, lo, hi = self._joint(spec, name, joints[name], default_model)
            self._motors.append(motor)
            zero.append(z), scale.append(s), low.append(lo), high.append(hi)
        if not self._motors:
            raise UserError("backends.dynamixel.joints: no joint is mapped to a servo")
        self.names = [m.name for m in self._motors]
        return RawMap(np.array(zero), np.array(scale), np.array(low, float), np.array(high, float))

    def _joint(
        self, spec: TargetSpec, name: str, j: DynamixelJoint, default: dt.Model
    ) -> tuple[Motor, float, float, int, int]:
        """Raw map of one joint; the options are typed and ranged, so only what depends on the
        servo's model and the profile's limits is checked here."""
        key = f"backends.dynamixel.joints.{name}"
        i = spec.index[name]
        model = dt.model(j.model) if j.model else default
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
        self._profile[name] = (
            self.options.profile_velocity if j.profile_velocity is None else j.profile_velocity,
            self.options.profile_acceleration if j.profile_acceleration is None else j.profile_acceleration,
        )
        self._limits[name] = (lo, hi)
        return Motor(name, j.id, model), z, s, lo, hi

    # ---------------------------------------------------------------- bus
    def _hw_open(self) -> None:
        self.bus = make_bus(self.options, self._motors)
        self.bus.connect()
        answering = {m.name for m in self._motors if self._check_model(m)}
        if answering:  # a reply lost on a noisy bus or a busy host is not a missing servo: ask again
            retry = [m for m in self._motors if m.name not in answering]
            answering |= {m.name for m in retry if any(self._check_model(m) for _ in range(OPEN_PINGS - 1))}
        if not answering:
            self.bus.disconnect()
            ids = ", ".join(str(m.id) for m in self._motors)
            raise UserError(f"{self.options.port}: no servo answers (ids {ids} at {self.bus.baudrate} baud)")
        missing = [m for m in self._motors if m.name not in answering]
        if missing:  # a servo the profile drives must be there, as a Maestro's channel must
            self.bus.disconnect()
            raise UserError(
                f"backends.dynamixel.joints.{missing[0].name}.id: servo {missing[0].id} does not answer on "
                f"{self.options.port} at {self.bus.baudrate} baud"
                + (f" (nor {', '.join(str(m.id) for m in missing[1:])})" if len(missing) > 1 else "")
            )
        self._setup(self.names)

    def _check_model(self, motor: Motor) -> bool:
        assert self.bus is not None
        found = self.bus.ping(motor.id)
        if found is None:
            return False
        if found[0] != motor.model.number:
            self.bus.disconnect()
            raise UserError(
                f"backends.dynamixel.joints.{motor.name}: servo {motor.id} is "
                f"{dt.model_name(found[0])}, the profile says {motor.model.name}"
            )
        return True

    def _setup(self, names: list[str]) -> None:
        """EEPROM (position limits, return delay; torque off, only if changed), profile, goal = present, torque on."""
        bus = self.bus
        assert bus is not None
        for name in names:
            table = bus.motors[name].table
            lo_reg, hi_reg = (
                ("Min_Position_Limit", "Max_Position_Limit")
                if table.has("Min_Position_Limit")
                else ("CW_Angle_Limit", "CCW_Angle_Limit")
            )
            lo, hi = self._limits[name]
            eeprom = {lo_reg: lo, hi_reg: hi, "Return_Delay_Time": self._return_delay}
            if any(bus.read(reg, name) != value for reg, value in eeprom.items()):
                bus.write("Torque_Enable", name, 0)
                for reg, value in eeprom.items():
                    bus.write(reg, name, value)
            velocity, acceleration = self._profile[name]
            bus.write("Profile_Velocity" if table.has("Profile_Velocity") else "Moving_Speed", name, velocity)
            if table.has("Profile_Acceleration"):
                bus.write("Profile_Acceleration", name, acceleration)
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
            h.voltage = regs["Present_Input_Voltage"] / 10.0
        for name in bus.take_alerts():
            status = bus.read("Hardware_Error_Status", name)
            if status:
                new = set(bus.motors[name].table.decode_errors(status)) - bus.health[name].faults_seen
                bus.note_hardware_error(name, status)
                for fault in sorted(new):
                    self._event(fault, name, f"Hardware_Error_Status 0x{status:02x}")
        for name in self.names:
            h = bus.health[name]
            if h.lost and name not in lost_before:
                self._event("servo_lost", name, f"no status packet after {bus.retries} retries")
            if h.timeouts:
                self._add_fault("lost_replies", name, f"{h.timeouts} status read(s) timed out")
            if h.corrupt:
                self._add_fault("bad_crc", name, f"{h.corrupt} status packet(s) failed their checksum")
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
