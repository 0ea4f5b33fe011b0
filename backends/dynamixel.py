"""Backend ``dynamixel``: a servo head on Dynamixel Protocol 2.0 servos (dynamixel-sdk).

Every frame becomes one SYNC_WRITE of goal ticks; the supervisor's health poll is one SYNC_READ of
present position, input voltage and temperature, plus Hardware_Error_Status for servos whose
status packets raise the alert bit. A servo that stops answering is retried with back-off and
re-initialised (limits, profile, torque) when it answers again. The safety loop itself (limits,
watchdog, ease to neutral, torque off) is ``servo_base.ServoBackend``; what this head shares with the
Feetech head (calibration, open checks, health poll, reconnect) is ``serial_bus_backend``.

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

from typing import Any, ClassVar

from convodrive.backends.servo import dynamixel_table as dt
from convodrive.backends.servo.dynamixel_bus import DynamixelBus
from convodrive.backends.servo.serial_bus_backend import SerialBusBackend
from convodrive.backends.servo.servo_bus import Motor
from convodrive.backends.servo.servo_options import DynamixelJoint, DynamixelOptions

HEALTH_REGISTERS = ["Present_Position", "Present_Input_Voltage", "Present_Temperature"]


class DynamixelBackend(SerialBusBackend):
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
    Bus = DynamixelBus
    Joint = DynamixelJoint
    lookup_model = staticmethod(dt.model)
    HEALTH_REGISTERS: ClassVar[list[str]] = HEALTH_REGISTERS
    VOLTAGE_REGISTER = "Present_Input_Voltage"
    CORRUPT_FAULT = "bad_crc"
    OPEN_PINGS = 3  # a servo the profile drives must answer one of three pings, or the run is refused

    def _motion_of(self, j: Any) -> tuple[int, int]:
        return (
            self.options.profile_velocity if j.profile_velocity is None else j.profile_velocity,
            self.options.profile_acceleration if j.profile_acceleration is None else j.profile_acceleration,
        )

    def _found_model(self, motor: Motor) -> tuple[bool, str] | None:
        assert self.bus is not None
        found = self.bus.ping(motor.id)
        return None if found is None else (found[0] == motor.model.number, dt.model_name(found[0]))

    def _limit_registers(self, table: Any) -> tuple[str, str]:
        if table.has("Min_Position_Limit"):
            return "Min_Position_Limit", "Max_Position_Limit"
        return "CW_Angle_Limit", "CCW_Angle_Limit"  # XL-320

    def _write_eeprom(self, name: str, values: dict[str, int]) -> None:
        """The EEPROM takes writes only with torque off."""
        assert self.bus is not None
        self.bus.write("Torque_Enable", name, 0)
        for reg, value in values.items():
            self.bus.write(reg, name, value)

    def _write_motion(self, name: str, speed: int, acceleration: int) -> None:
        bus = self.bus
        assert bus is not None
        table = bus.motors[name].table
        bus.write("Profile_Velocity" if table.has("Profile_Velocity") else "Moving_Speed", name, speed)
        if table.has("Profile_Acceleration"):
            bus.write("Profile_Acceleration", name, acceleration)
