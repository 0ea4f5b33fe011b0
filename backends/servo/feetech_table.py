"""Feetech STS/SMS and SCS register maps as data: addresses, sizes, byte order, sign bits, units.

The bus, the backend and the emulator address registers by name through these tables, so a new
model is a new entry here rather than new code. Addresses follow Feetech's memory tables (the same
ones LeRobot's ``feetech`` tables transcribe): torque enable 40, goal position 42, present
position 56, present load 60, voltage 62, temperature 63.

Two things differ from Dynamixel's tables. Words are little-endian on STS/SMS (``scservo_sdk``'s
``protocol_end`` 0) and big-endian on SCS (``protocol_end`` 1). Negative values are not two's
complement: a sign bit (bit 15 of a position or speed word, bit 11 of the homing offset, bit 10 of
the load) carries the sign and the other bits the magnitude. The SDK keeps the byte order in a
process-wide global, so the bus encodes and decodes registers itself, here, per servo.
"""

from __future__ import annotations

import dataclasses
import math

from convodrive.backends.servo.register_map import RegisterMap
from convodrive.plumbing.errors import UserError


@dataclasses.dataclass(frozen=True)
class Register:
    address: int
    size: int
    sign_bit: int | None = None
    """Bit that carries the sign (sign and magnitude); None for unsigned registers."""
    eeprom: bool = False
    """Kept across power cycles only when written with ``Lock`` 0."""
    writable: bool = True


@dataclasses.dataclass(frozen=True, eq=False)
class FeetechTable(RegisterMap):
    """One series' register map, byte order and the facts that turn steps into radians."""

    family: str
    registers: dict[str, Register]
    big_endian: bool
    sync_read: bool
    """Whether the firmware answers SYNC_READ (0x82); SCS servos are read one at a time."""
    resolution: int
    """Steps over ``span_rad``."""
    span_rad: float
    center_tick: int
    max_speed: float
    """No-load speed in steps per second (what a Goal_Velocity of 0 means: as fast as it goes)."""
    error_bits: dict[int, str]
    """Status-packet error bit -> fault name (the same bits as the ``Status`` register)."""
    defaults: dict[str, int]
    """Factory values the emulator starts from (besides model number and ID)."""

    def encode(self, value: int, reg: Register) -> bytes:
        """Bytes of a register value in this series' byte order, sign bit set for negatives."""
        magnitude = abs(int(value))
        limit = 1 << (reg.sign_bit if reg.sign_bit is not None else 8 * reg.size)
        if (value < 0 and reg.sign_bit is None) or magnitude >= limit:
            raise ValueError(f"value {value} does not fit {reg.size} byte(s)")
        raw = magnitude | (1 << reg.sign_bit) if value < 0 and reg.sign_bit is not None else magnitude
        return raw.to_bytes(reg.size, "big" if self.big_endian else "little")

    def decode(self, data: bytes | list[int], reg: Register) -> int:
        raw = int.from_bytes(bytes(data[: reg.size]), "big" if self.big_endian else "little")
        if reg.sign_bit is not None and raw & (1 << reg.sign_bit):
            return -(raw & ~(1 << reg.sign_bit))
        return raw


def _r(address: int, size: int, sign_bit: int | None = None, **kw: bool) -> Register:
    return Register(address, size, sign_bit, **kw)


_EEPROM_COMMON = {
    "Firmware_Major_Version": _r(0, 1, eeprom=True, writable=False),
    "Firmware_Minor_Version": _r(1, 1, eeprom=True, writable=False),
    "Model_Number": _r(3, 2, eeprom=True, writable=False),
    "ID": _r(5, 1, eeprom=True),
    "Baud_Rate": _r(6, 1, eeprom=True),
    "Return_Delay_Time": _r(7, 1, eeprom=True),
    "Response_Status_Level": _r(8, 1, eeprom=True),
    "Min_Position_Limit": _r(9, 2, eeprom=True),
    "Max_Position_Limit": _r(11, 2, eeprom=True),
    "Max_Temperature_Limit": _r(13, 1, eeprom=True),
    "Max_Voltage_Limit": _r(14, 1, eeprom=True),
    "Min_Voltage_Limit": _r(15, 1, eeprom=True),
    "Max_Torque_Limit": _r(16, 2, eeprom=True),
    "Phase": _r(18, 1, eeprom=True),
    "Unloading_Condition": _r(19, 1, eeprom=True),
    "LED_Alarm_Condition": _r(20, 1, eeprom=True),
    "P_Coefficient": _r(21, 1, eeprom=True),
    "D_Coefficient": _r(22, 1, eeprom=True),
    "I_Coefficient": _r(23, 1, eeprom=True),
    "Minimum_Startup_Force": _r(24, 2, eeprom=True),
    "CW_Dead_Zone": _r(26, 1, eeprom=True),
    "CCW_Dead_Zone": _r(27, 1, eeprom=True),
}
_PRESENT = {
    "Torque_Enable": _r(40, 1),
    "Acceleration": _r(41, 1),
    "Goal_Position": _r(42, 2, 15),
    "Goal_Time": _r(44, 2),
    "Goal_Velocity": _r(46, 2, 15),
    "Present_Position": _r(56, 2, 15, writable=False),
    "Present_Velocity": _r(58, 2, 15, writable=False),
    "Present_Load": _r(60, 2, 10, writable=False),
    "Present_Voltage": _r(62, 1, writable=False),
    "Present_Temperature": _r(63, 1, writable=False),
    "Status": _r(65, 1, writable=False),
    "Moving": _r(66, 1, writable=False),
}
ERROR_BITS = {0: "input_voltage", 1: "angle_sensor", 2: "overheating", 3: "overcurrent", 5: "overload"}
"""The status packet's error byte (scservo_sdk's ERRBIT_VOLTAGE 1, ANGLE 2, OVERHEAT 4, OVERELE 8, OVERLOAD 32)."""
_DEFAULTS_COMMON = {
    "Baud_Rate": 0,  # 1 Mbps
    "Return_Delay_Time": 250,  # 2 us units: 500 us
    "Response_Status_Level": 1,  # answer every instruction
    "Max_Temperature_Limit": 70,
    "Unloading_Condition": 0b101100,  # overheating, overcurrent, overload switch torque off
    "LED_Alarm_Condition": 0b101111,
    "P_Coefficient": 32,
    "Present_Temperature": 30,
    "Lock": 1,
}

STS = FeetechTable(
    family="sts",
    registers={
        **_EEPROM_COMMON,
        "Protection_Current": _r(28, 2, eeprom=True),
        "Angular_Resolution": _r(30, 1, eeprom=True),
        "Homing_Offset": _r(31, 2, 11, eeprom=True),
        "Operating_Mode": _r(33, 1, eeprom=True),
        "Protective_Torque": _r(34, 1, eeprom=True),
        "Protection_Time": _r(35, 1, eeprom=True),
        "Overload_Torque": _r(36, 1, eeprom=True),
        **_PRESENT,
        "Torque_Limit": _r(48, 2),
        "Lock": _r(55, 1),
        "Present_Current": _r(69, 2, 15, writable=False),
    },
    big_endian=False,
    sync_read=True,
    resolution=4096,
    span_rad=2 * math.pi,
    center_tick=2048,
    max_speed=3073.0,  # 0.222 s per 60 degrees at 12 V
    error_bits=ERROR_BITS,
    defaults={
        **_DEFAULTS_COMMON,
        "Max_Position_Limit": 4095,
        "Max_Voltage_Limit": 140,
        "Min_Voltage_Limit": 40,
        "Max_Torque_Limit": 1000,
        "Torque_Limit": 1000,
        "Goal_Position": 2048,
        "Present_Position": 2048,
        "Present_Voltage": 120,
    },
)

SCS = FeetechTable(
    family="scs",
    registers={
        **_EEPROM_COMMON,
        "Protective_Torque": _r(37, 1, eeprom=True),
        "Protection_Time": _r(38, 1, eeprom=True),
        **_PRESENT,
        "Lock": _r(48, 1),
    },
    big_endian=True,
    sync_read=False,
    resolution=1024,
    span_rad=math.radians(300.0),
    center_tick=512,
    max_speed=2048.0,  # 0.1 s per 60 degrees at 6 V
    error_bits=ERROR_BITS,
    defaults={
        **_DEFAULTS_COMMON,
        "Max_Position_Limit": 1023,
        "Max_Voltage_Limit": 90,
        "Min_Voltage_Limit": 40,
        "Max_Torque_Limit": 1000,
        "Goal_Position": 512,
        "Present_Position": 512,
        "Present_Voltage": 60,
    },
)


@dataclasses.dataclass(frozen=True)
class Model:
    name: str
    number: int
    table: FeetechTable
    firmware: tuple[int, int] = (3, 10)


MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        Model("sts3215", 777, STS),
        Model("sts3250", 2825, STS),
        Model("sm8512bl", 11272, STS),
        Model("scs0009", 1284, SCS),
    )
}
ALIASES = {"sts": "sts3215", "scs": "scs0009", "so100": "sts3215"}
MODEL_NAMES = tuple(sorted([*MODELS, *ALIASES]))

# Baud_Rate register value -> bits per second.
BAUD_RATES = {0: 1_000_000, 1: 500_000, 2: 250_000, 3: 128_000, 4: 115_200, 5: 76_800, 6: 57_600, 7: 38_400}


def model(name: str) -> Model:
    """Look a model up by name or alias (case-insensitive); a UserError names the known ones."""
    key = ALIASES.get(name.lower(), name.lower())
    if key not in MODELS:
        raise UserError(f"unknown Feetech model {name!r} (known: {', '.join(MODEL_NAMES)})")
    return MODELS[key]


def identify(data: bytes | list[int]) -> str:
    """The model whose number the two Model_Number bytes spell in its own byte order."""
    for m in MODELS.values():
        if m.table.decode(data, m.table.reg("Model_Number")) == m.number:
            return m.name
    return f"unknown({bytes(data[:2]).hex()})"
