"""Dynamixel control tables as data: register addresses, sizes and units per servo model.

The bus, the backend and the emulator all address registers by name through these tables, so a
new model is a new entry here rather than new code. Register names follow the ROBOTIS e-manual
(``Goal_Position``, ``Present_Position``, ...). The XL-320 speaks Protocol 2.0 but has its own
table (2-byte positions, 1024 ticks over 300 degrees, no profile acceleration).
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
    signed: bool = False
    eeprom: bool = False
    """EEPROM registers can only be written with torque off (the servo answers Access Error)."""
    writable: bool = True


@dataclasses.dataclass(frozen=True, eq=False)
class ControlTable(RegisterMap):
    """One family's register map plus the facts needed to turn ticks into radians."""

    family: str
    registers: dict[str, Register]
    resolution: int
    """Ticks over ``span_rad``."""
    span_rad: float
    center_tick: int
    velocity_unit_rpm: float
    """Unit of Profile_Velocity (X-series) or Moving_Speed (XL-320), in rev/min."""
    acceleration_unit_rpm2: float | None
    """Unit of Profile_Acceleration in rev/min^2; None where the model has none (XL-320)."""
    error_bits: dict[int, str]
    """Hardware_Error_Status bit -> fault name."""
    defaults: dict[str, int]
    """Factory values the emulator starts from (besides model number and ID)."""

    def encode(self, value: int, reg: Register) -> list[int]:
        """``encode`` (the same little-endian words for every family): ``servo_bus`` asks the table."""
        return encode(value, reg)

    def decode(self, data: bytes | list[int], reg: Register) -> int:
        return decode(data, reg)


def _r(address: int, size: int, **kw: bool) -> Register:
    return Register(address, size, **kw)


X_SERIES = ControlTable(
    family="x-series",
    registers={
        "Model_Number": _r(0, 2, eeprom=True, writable=False),
        "Model_Information": _r(2, 4, eeprom=True, writable=False),
        "Firmware_Version": _r(6, 1, eeprom=True, writable=False),
        "ID": _r(7, 1, eeprom=True),
        "Baud_Rate": _r(8, 1, eeprom=True),
        "Return_Delay_Time": _r(9, 1, eeprom=True),
        "Drive_Mode": _r(10, 1, eeprom=True),
        "Operating_Mode": _r(11, 1, eeprom=True),
        "Homing_Offset": _r(20, 4, signed=True, eeprom=True),
        "Temperature_Limit": _r(31, 1, eeprom=True),
        "Max_Voltage_Limit": _r(32, 2, eeprom=True),
        "Min_Voltage_Limit": _r(34, 2, eeprom=True),
        "Velocity_Limit": _r(44, 4, eeprom=True),
        "Max_Position_Limit": _r(48, 4, eeprom=True),
        "Min_Position_Limit": _r(52, 4, eeprom=True),
        "Shutdown": _r(63, 1, eeprom=True),
        "Torque_Enable": _r(64, 1),
        "LED": _r(65, 1),
        "Status_Return_Level": _r(68, 1),
        "Registered_Instruction": _r(69, 1, writable=False),
        "Hardware_Error_Status": _r(70, 1, writable=False),
        "Position_D_Gain": _r(80, 2),
        "Position_I_Gain": _r(82, 2),
        "Position_P_Gain": _r(84, 2),
        "Profile_Acceleration": _r(108, 4),
        "Profile_Velocity": _r(112, 4),
        "Goal_Position": _r(116, 4, signed=True),
        "Moving": _r(122, 1, writable=False),
        "Present_Current": _r(126, 2, signed=True, writable=False),
        "Present_Velocity": _r(128, 4, signed=True, writable=False),
        "Present_Position": _r(132, 4, signed=True, writable=False),
        "Present_Input_Voltage": _r(144, 2, writable=False),
        "Present_Temperature": _r(146, 1, writable=False),
    },
    resolution=4096,
    span_rad=2 * math.pi,
    center_tick=2048,
    velocity_unit_rpm=0.229,
    acceleration_unit_rpm2=214.577,
    error_bits={0: "input_voltage", 2: "overheating", 3: "motor_encoder", 4: "electrical_shock", 5: "overload"},
    defaults={
        "Baud_Rate": 1,
        "Return_Delay_Time": 250,
        "Operating_Mode": 3,
        "Temperature_Limit": 70,
        "Max_Voltage_Limit": 70,
        "Min_Voltage_Limit": 35,
        "Velocity_Limit": 445,
        "Max_Position_Limit": 4095,
        "Min_Position_Limit": 0,
        "Shutdown": 52,
        "Status_Return_Level": 2,
        "Position_P_Gain": 400,
        "Goal_Position": 2048,
        "Present_Position": 2048,
        "Present_Input_Voltage": 50,
        "Present_Temperature": 30,
    },
)

XL320 = ControlTable(
    family="xl320",
    registers={
        "Model_Number": _r(0, 2, eeprom=True, writable=False),
        "Firmware_Version": _r(2, 1, eeprom=True, writable=False),
        "ID": _r(3, 1, eeprom=True),
        "Baud_Rate": _r(4, 1, eeprom=True),
        "Return_Delay_Time": _r(5, 1, eeprom=True),
        "CW_Angle_Limit": _r(6, 2, eeprom=True),
        "CCW_Angle_Limit": _r(8, 2, eeprom=True),
        "Control_Mode": _r(11, 1, eeprom=True),
        "Temperature_Limit": _r(12, 1, eeprom=True),
        "Min_Voltage_Limit": _r(13, 1, eeprom=True),
        "Max_Voltage_Limit": _r(14, 1, eeprom=True),
        "Max_Torque": _r(15, 2, eeprom=True),
        "Status_Return_Level": _r(17, 1, eeprom=True),
        "Shutdown": _r(18, 1, eeprom=True),
        "Torque_Enable": _r(24, 1),
        "LED": _r(25, 1),
        "D_Gain": _r(27, 1),
        "I_Gain": _r(28, 1),
        "P_Gain": _r(29, 1),
        "Goal_Position": _r(30, 2),
        "Moving_Speed": _r(32, 2),
        "Torque_Limit": _r(35, 2),
        "Present_Position": _r(37, 2, writable=False),
        "Present_Speed": _r(39, 2, writable=False),
        "Present_Load": _r(41, 2, writable=False),
        "Present_Input_Voltage": _r(45, 1, writable=False),
        "Present_Temperature": _r(46, 1, writable=False),
        "Registered_Instruction": _r(47, 1, writable=False),
        "Moving": _r(49, 1, writable=False),
        "Hardware_Error_Status": _r(50, 1, writable=False),
        "Punch": _r(51, 2),
    },
    resolution=1024,
    span_rad=math.radians(300.0),
    center_tick=512,
    velocity_unit_rpm=0.111,
    acceleration_unit_rpm2=None,
    error_bits={0: "overload", 1: "overheating", 2: "input_voltage"},
    defaults={
        "Baud_Rate": 3,
        "Return_Delay_Time": 250,
        "Control_Mode": 2,
        "Temperature_Limit": 65,
        "Min_Voltage_Limit": 60,
        "Max_Voltage_Limit": 90,
        "Max_Torque": 1023,
        "Status_Return_Level": 2,
        "Shutdown": 3,
        "CCW_Angle_Limit": 1023,
        "P_Gain": 32,
        "Torque_Limit": 1023,
        "Punch": 32,
        "Goal_Position": 512,
        "Present_Position": 512,
        "Present_Input_Voltage": 74,
        "Present_Temperature": 30,
    },
)


@dataclasses.dataclass(frozen=True)
class Model:
    name: str
    number: int
    table: ControlTable
    firmware: int = 52


MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        Model("xl330-m077", 1190, X_SERIES),
        Model("xl330-m288", 1200, X_SERIES),
        Model("xc330-t288", 1220, X_SERIES),
        Model("xl430-w250", 1060, X_SERIES),
        Model("xm430-w350", 1020, X_SERIES),
        Model("xm430-w210", 1030, X_SERIES),
        Model("xm540-w270", 1120, X_SERIES),
        Model("xh430-w350", 1010, X_SERIES),
        Model("xl320", 350, XL320, firmware=35),
    )
}
ALIASES = {
    "xl330": "xl330-m288",
    "xm430": "xm430-w350",
    "xl430": "xl430-w250",
    "xc330": "xc330-t288",
    "xl-320": "xl320",
}
MODEL_BY_NUMBER: dict[int, Model] = {m.number: m for m in MODELS.values()}

# Baud_Rate register value -> bits per second (X-series; the XL-320 uses 0..3 for the first four).
BAUD_RATES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000}


def model(name: str) -> Model:
    """Look a model up by name or alias (case-insensitive); a UserError names the known ones."""
    key = ALIASES.get(name.lower(), name.lower())
    if key not in MODELS:
        known = ", ".join(sorted([*MODELS, *ALIASES]))
        raise UserError(f"unknown Dynamixel model {name!r} (known: {known})")
    return MODELS[key]


def model_name(number: int) -> str:
    found = MODEL_BY_NUMBER.get(number)
    return found.name if found else f"unknown({number})"


def encode(value: int, reg: Register) -> list[int]:
    """Little-endian bytes of a register value; signed registers use two's complement."""
    bits = 8 * reg.size
    if reg.signed and value < 0:
        value += 1 << bits
    if not 0 <= value < (1 << bits):
        raise ValueError(f"value {value} does not fit {reg.size} bytes")
    return [(value >> (8 * i)) & 0xFF for i in range(reg.size)]


def decode(data: bytes | list[int], reg: Register) -> int:
    value = int.from_bytes(bytes(data[: reg.size]), "little")
    if reg.signed and value >= 1 << (8 * reg.size - 1):
        value -= 1 << (8 * reg.size)
    return value
