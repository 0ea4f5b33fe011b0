"""The options of the servo heads, declared once (``convodrive.plugins.options``).

The backends (``dynamixel``, ``maestro``) and the servo tools (``convodrive servo``) read these
declarations, so the profile's ``backends:`` section, ``-B`` and the tools' flags agree on names,
ranges and help. This module imports neither dynamixel-sdk nor pyserial: the options can be listed
and checked without the hardware extra.
"""

from __future__ import annotations

import dataclasses

from convodrive.backends.base import RobotOptions
from convodrive.backends.servo import dynamixel_table as dt
from convodrive.plugins.options import REQUIRED, PluginOptions, option


@dataclasses.dataclass(frozen=True)
class ServoOptions(RobotOptions):
    """Options every servo head takes: where it is and how the safety loop paces it."""

    port: str = option("", help="Serial port, e.g. /dev/ttyUSB0 (or the path `convodrive emulate` prints)")
    read_rate: float = option(
        10.0, low=0.5, high=100, help="Health reads per second (position, temperature, voltage, errors), after a frame"
    )
    watchdog_s: float = option(0.5, low=0.05, high=10, help="Ease to neutral when no frame came for this long (s)")
    ease_s: float = option(
        1.0, low=0.1, high=10, help="Ease-to-neutral time on close, error or signal, then torque off (s)"
    )


MODEL_NAMES = tuple(sorted([*dt.MODELS, *dt.ALIASES]))
MAX_TICK = 4095
MAX_PROFILE = 32767


@dataclasses.dataclass(frozen=True)
class DynamixelJoint(PluginOptions):
    """One servo of the head: which id drives a profile joint, and its calibration in raw ticks."""

    id: int = option(REQUIRED, low=0, high=252, help="Servo id on the bus")
    model: str | None = option(None, choices=MODEL_NAMES, help="This servo's model; default: the bus's model")
    zero_tick: float | None = option(None, low=0, high=MAX_TICK, help="Tick at joint value 0; default: the centre")
    direction: int = option(1, choices=(1, -1), help="1, or -1 when the servo turns the other way")
    min_tick: int | None = option(None, low=0, high=MAX_TICK, help="Lowest tick; default: from the joint limits")
    max_tick: int | None = option(None, low=0, high=MAX_TICK, help="Highest tick; default: from the joint limits")
    ticks_per_unit: float | None = option(
        None, low=1e-3, high=1e6, help="Ticks per joint unit; default: ticks per radian (needed for norm joints)"
    )
    profile_velocity: int | None = option(
        None, low=0, high=MAX_PROFILE, help="Profile_Velocity, raw units (0 = unlimited); default: the bus's"
    )
    profile_acceleration: int | None = option(
        None, low=0, high=MAX_PROFILE, help="Profile_Acceleration, raw units (0 = unlimited); default: the bus's"
    )

    def __post_init__(self) -> None:
        if self.min_tick is not None and self.max_tick is not None and self.min_tick > self.max_tick:
            raise ValueError(f"min_tick {self.min_tick} is above max_tick {self.max_tick}")


@dataclasses.dataclass(frozen=True)
class DynamixelOptions(ServoOptions):
    baudrate: int = option(1_000_000, low=9600, high=4_500_000, help="Bus speed in bits per second")
    protocol: int = option(2, choices=(2,), help="Dynamixel protocol version (2.0 only)")
    model: str = option("xl330", choices=MODEL_NAMES, help="Servo model of every joint that names none")
    retries: int = option(2, low=0, high=10, help="Retries per lost status packet, with back-off")
    latency_ms: float = option(
        16.0, low=0, high=255, help="USB adapter latency timer (FTDI default 16; 1 if you lowered it)"
    )
    return_delay_us: int = option(0, low=0, high=508, help="Return_Delay_Time written to each servo, microseconds")
    profile_velocity: int = option(0, low=0, high=MAX_PROFILE, help="Profile_Velocity of joints that give none")
    profile_acceleration: int = option(0, low=0, high=MAX_PROFILE, help="Profile_Acceleration of joints that give none")
    joints: dict[str, DynamixelJoint] | None = option(
        None, max_items=253, help="Profile joint name to its servo; default: the joints take ids 1..N"
    )

    def __post_init__(self) -> None:
        ids = [j.id for j in (self.joints or {}).values()]
        twice = sorted({i for i in ids if ids.count(i) > 1})
        if twice:
            raise ValueError(f"option 'joints': servo id {twice[0]} is used by more than one joint")


MIN_US, MAX_US = 64.0, 4000.0
CHANNEL_COUNTS = (6, 12, 18, 24)  # Micro Maestro 6, Mini Maestro 12, 18, 24


@dataclasses.dataclass(frozen=True)
class MaestroJoint(PluginOptions):
    """One channel of the controller: which profile joint it drives, as pulse widths."""

    channel: int = option(REQUIRED, low=0, high=max(CHANNEL_COUNTS) - 1, help="Servo channel on the Maestro")
    zero_us: float = option(1500.0, low=MIN_US, high=MAX_US, help="Pulse width at joint value 0, microseconds")
    us_per_unit: float = option(
        600.0, low=-MAX_US, high=MAX_US, help="Microseconds per joint unit (negative reverses the servo)"
    )
    min_us: float = option(1000.0, low=MIN_US, high=MAX_US, help="Shortest pulse, microseconds")
    max_us: float = option(2000.0, low=MIN_US, high=MAX_US, help="Longest pulse, microseconds")
    speed: int = option(0, low=0, high=(1 << 14) - 1, help="Maestro speed limit (0.25 us per 10 ms; 0 = none)")
    acceleration: int = option(0, low=0, high=255, help="Maestro acceleration limit (0 = none)")

    def __post_init__(self) -> None:
        if self.us_per_unit == 0:
            raise ValueError("us_per_unit must not be 0")
        if self.min_us > self.max_us:
            raise ValueError(f"min_us {self.min_us:g} is above max_us {self.max_us:g}")


@dataclasses.dataclass(frozen=True)
class MaestroOptions(ServoOptions):
    read_rate: float = option(5.0, low=0.5, high=100, help="Error and position reads per second, after a frame")
    baudrate: int = option(115200, low=300, high=250_000, help="Serial speed (the USB command port ignores it)")
    device: int | None = option(
        None, low=0, high=127, help="Pololu protocol device number; default: the compact protocol"
    )
    timeout_s: float = option(0.05, low=0.001, high=1, help="How long to wait for a reply (s)")
    channels: int | None = option(
        None,
        choices=CHANNEL_COUNTS,
        help="Channels of this Maestro (6, 12, 18, 24); default: every mapped channel is asked at open",
    )
    joints: dict[str, MaestroJoint] | None = option(
        None, max_items=24, help="Profile joint name to its channel; default: the joints take channels 0..N-1"
    )

    def __post_init__(self) -> None:
        used = [j.channel for j in (self.joints or {}).values()]
        twice = sorted({c for c in used if used.count(c) > 1})
        if twice:
            raise ValueError(f"option 'joints': channel {twice[0]} is used by more than one joint")
        if self.channels is not None and used and max(used) >= self.channels:
            name = next(n for n, j in (self.joints or {}).items() if j.channel == max(used))
            raise ValueError(
                f"option 'joints.{name}.channel': {max(used)} is not a channel of a {self.channels}-channel Maestro "
                f"(0..{self.channels - 1})"
            )
