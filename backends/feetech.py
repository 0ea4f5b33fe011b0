"""Backend ``feetech``: a servo head on Feetech STS/SCS serial-bus servos (feetech-servo-sdk).

Every frame becomes one SYNC_WRITE of goal steps; the supervisor's health poll is one SYNC_READ
(STS; SCS servos one READ each) of present position, load, voltage and temperature, whose status
packets also carry each servo's fault bits. A servo that stops answering is retried with back-off
and re-initialised (limits, speed, torque) when it answers again. The safety loop itself (limits,
watchdog, ease to neutral, torque off) is ``servo_base.ServoBackend``, and what it shares with the
Dynamixel head (calibration, open checks, health poll, reconnect) ``serial_bus_backend``.

Options: ``FeetechOptions`` (``convodrive plugins feetech`` lists them), usually in the robot
profile's ``backends.feetech``, one ``joints`` entry per servo, the Dynamixel head's format::

    joints:
      neck_pan: {id: 1, zero_tick: 2048, direction: 1, min_tick: 1135, max_tick: 2961, velocity: 2000}

``ticks_per_unit`` defaults to steps per radian; joints missing from ``joints`` are not driven;
without ``joints`` the spec's joints take ids 1..N with the model's centre step as zero.
"""

from __future__ import annotations

from typing import Any, ClassVar

from convodrive.backends.servo import feetech_table as ft
from convodrive.backends.servo.feetech_bus import FeetechBus
from convodrive.backends.servo.feetech_options import FeetechJoint, FeetechOptions
from convodrive.backends.servo.serial_bus_backend import SerialBusBackend
from convodrive.backends.servo.servo_bus import Motor

HEALTH_REGISTERS = ["Present_Position", "Present_Load", "Present_Voltage", "Present_Temperature"]


class FeetechBackend(SerialBusBackend):
    name = "feetech"
    description = "Feetech STS/SCS serial-bus servo head (STS3215, SCS0009, ...) over feetech-servo-sdk"
    realtime = True
    hardware = True
    may_run_in_process = True
    default_profile = "servo_head"
    requires = ("scservo_sdk", "serial")
    extra = "hardware"
    Options = FeetechOptions
    options: FeetechOptions
    Bus = FeetechBus
    Joint = FeetechJoint
    lookup_model = staticmethod(ft.model)
    HEALTH_REGISTERS: ClassVar[list[str]] = HEALTH_REGISTERS
    VOLTAGE_REGISTER = "Present_Voltage"
    CORRUPT_FAULT = "bad_checksum"
    REFUSE_MISSING = False  # a servo missing at open is lost (and re-initialised when it answers)

    def _motion_of(self, j: Any) -> tuple[int, int]:
        return (
            self.options.velocity if j.velocity is None else j.velocity,
            self.options.acceleration if j.acceleration is None else j.acceleration,
        )

    def _found_model(self, motor: Motor) -> tuple[bool, str] | None:
        assert self.bus is not None
        found = self.bus.ping(motor.id)  # the bus's ping retries: a lost reply is no absence
        return None if found is None else (found == motor.model.name, found)

    def _write_eeprom(self, name: str, values: dict[str, int]) -> None:
        """The EEPROM keeps writes made with ``Lock`` 0; locked again after."""
        assert self.bus is not None
        self.bus.write("Lock", name, 0)
        for reg, value in values.items():
            self.bus.write(reg, name, value)
        self.bus.write("Lock", name, 1)

    def _write_motion(self, name: str, speed: int, acceleration: int) -> None:
        assert self.bus is not None
        self.bus.write("Goal_Velocity", name, speed)
        self.bus.write("Acceleration", name, acceleration)
