"""The ``feetech`` backend's options, declared once (``convodrive.plugins.options``).

The joint entries have the Dynamixel head's shape (``id``, ``zero_tick``, ``direction``,
``min_tick``, ``max_tick``, ``ticks_per_unit``), so one calibration format serves both buses
(``convodrive servo``'s ``set_joint_limits`` edits ``backends.feetech`` as it does ``dynamixel``).
This module imports no SDK:
the options can be listed and checked without the hardware extra.
"""

from __future__ import annotations

import dataclasses

from convodrive.backends.servo.feetech_table import MODEL_NAMES
from convodrive.backends.servo.servo_options import ServoOptions
from convodrive.plugins.options import REQUIRED, PluginOptions, option

MAX_TICK = 4095
MAX_SPEED = 32767  # Goal_Velocity: 15 bits of magnitude


@dataclasses.dataclass(frozen=True)
class FeetechJoint(PluginOptions):
    """One servo of the head: which id drives a profile joint, and its calibration in raw steps."""

    id: int = option(REQUIRED, low=0, high=252, help="Servo id on the bus")
    model: str | None = option(None, choices=MODEL_NAMES, help="This servo's model; default: the bus's model")
    zero_tick: float | None = option(None, low=0, high=MAX_TICK, help="Step at joint value 0; default: the centre")
    direction: int = option(1, choices=(1, -1), help="1, or -1 when the servo turns the other way")
    min_tick: int | None = option(None, low=0, high=MAX_TICK, help="Lowest step; default: from the joint limits")
    max_tick: int | None = option(None, low=0, high=MAX_TICK, help="Highest step; default: from the joint limits")
    ticks_per_unit: float | None = option(
        None, low=1e-3, high=1e6, help="Steps per joint unit; default: steps per radian (needed for norm joints)"
    )
    velocity: int | None = option(
        None, low=0, high=MAX_SPEED, help="Goal_Velocity, steps per second (0 = full speed); default: the bus's"
    )
    acceleration: int | None = option(
        None, low=0, high=254, help="Acceleration, 100 steps/s^2 (0 = none); default: the bus's"
    )

    def __post_init__(self) -> None:
        if self.min_tick is not None and self.max_tick is not None and self.min_tick > self.max_tick:
            raise ValueError(f"min_tick {self.min_tick} is above max_tick {self.max_tick}")


@dataclasses.dataclass(frozen=True)
class FeetechOptions(ServoOptions):
    baudrate: int = option(1_000_000, low=4800, high=1_000_000, help="Bus speed in bits per second")
    model: str = option("sts3215", choices=MODEL_NAMES, help="Servo model of every joint that names none")
    retries: int = option(2, low=0, high=10, help="Retries per lost or corrupt status packet, with back-off")
    latency_ms: float = option(
        16.0, low=0, high=255, help="USB adapter latency timer (FTDI/CH340 default 16; 1 if you lowered it)"
    )
    return_delay_us: int = option(0, low=0, high=508, help="Return_Delay_Time written to each servo, microseconds")
    velocity: int = option(0, low=0, high=MAX_SPEED, help="Goal_Velocity of joints that give none (0 = full speed)")
    acceleration: int = option(0, low=0, high=254, help="Acceleration of joints that give none (0 = none)")
    joints: dict[str, FeetechJoint] | None = option(
        None, max_items=253, help="Profile joint name to its servo; default: the joints take ids 1..N"
    )

    def __post_init__(self) -> None:
        ids = [j.id for j in (self.joints or {}).values()]
        twice = sorted({i for i in ids if ids.count(i) > 1})
        if twice:
            raise ValueError(f"option 'joints': servo id {twice[0]} is used by more than one joint")
