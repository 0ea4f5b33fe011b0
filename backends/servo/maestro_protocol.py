"""Pololu Maestro serial commands (compact protocol), as bytes.

Targets are in quarter-microseconds (6000 = 1500 us); data bytes carry 7 bits each, so a 14-bit
value goes low 7 bits first. The Pololu protocol is the same command with its top bit cleared,
prefixed by 0xAA and a device number; ``pololu(device, command)`` converts one.
"""

from __future__ import annotations

SET_TARGET, SET_MULTIPLE_TARGETS, SET_SPEED, SET_ACCELERATION = 0x84, 0x9F, 0x87, 0x89
GET_POSITION, GET_MOVING_STATE, GET_ERRORS, GO_HOME = 0x90, 0x93, 0xA1, 0xA2

ERROR_BITS = {
    0: "serial_signal",
    1: "serial_overrun",
    2: "serial_buffer_full",
    3: "serial_crc",
    4: "serial_protocol",
    5: "serial_timeout",
    6: "script_stack",
    7: "script_call_stack",
    8: "script_program_counter",
}


def _word(value: int) -> bytes:
    if not 0 <= value < 1 << 14:
        raise ValueError(f"{value} does not fit the Maestro's 14-bit data")
    return bytes([value & 0x7F, (value >> 7) & 0x7F])


def set_target(channel: int, quarter_us: int) -> bytes:
    """0 stops the pulses on that channel: a hobby servo goes limp (its 'torque off')."""
    return bytes([SET_TARGET, channel]) + _word(quarter_us)


def set_speed(channel: int, speed: int) -> bytes:
    """Speed limit in 0.25 us per 10 ms; 0 = unlimited."""
    return bytes([SET_SPEED, channel]) + _word(speed)


def set_acceleration(channel: int, acceleration: int) -> bytes:
    """Acceleration limit in 0.25 us per 10 ms per 80 ms (0..255); 0 = unlimited."""
    return bytes([SET_ACCELERATION, channel]) + _word(acceleration)


def get_position(channel: int) -> bytes:
    return bytes([GET_POSITION, channel])


def get_errors() -> bytes:
    return bytes([GET_ERRORS])


def pololu(device: int, command: bytes) -> bytes:
    return bytes([0xAA, device, command[0] & 0x7F]) + command[1:]


def decode_errors(bits: int) -> list[str]:
    return [name for bit, name in ERROR_BITS.items() if bits & (1 << bit)]
