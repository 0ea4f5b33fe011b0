"""Dynamixel Protocol 2.0 framing written from the protocol description, for the emulator.

The emulator must not reuse the SDK's framing code, or a shared bug would pass unnoticed; tests
check this CRC against the SDK's. Packet: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params |
CRC_L CRC_H`` where LEN counts INST, the (stuffed) params and the CRC. Any ``FF FF FD`` inside
INST..params gets an extra ``FD``; the CRC is computed over the stuffed bytes.
"""

from __future__ import annotations

import dataclasses

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC

PING, READ, WRITE, REG_WRITE, ACTION, FACTORY_RESET, REBOOT, CLEAR = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x08, 0x10
STATUS, SYNC_READ, SYNC_WRITE, BULK_READ, BULK_WRITE = 0x55, 0x82, 0x83, 0x92, 0x93

# Status packet error byte: bit 7 = hardware alert, low bits = error number.
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE, ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = (
    1,
    2,
    3,
    4,
    5,
    6,
    7,
)
ERR_ALERT = 0x80


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_TABLE = _crc_table()


def crc16(data: bytes | bytearray) -> int:
    """CRC-16 with polynomial 0x8005, initial value 0, MSB first, no final xor."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ _TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert 0xFD after every FF FF FD in the instruction-and-params region."""
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if (
            body[i] == 0xFD
            and len(out) >= 3
            and out[-3] == 0xFF
            and out[-2] == 0xFF
            and i + 1 < len(body)
            and body[i + 1] == 0xFD
        ):
            i += 1  # drop the stuffed FD
        i += 1
    return bytes(out)


def build(servo_id: int, body: bytes) -> bytes:
    """Frame ``body`` (instruction or 0x55+error, then params) with header, length and CRC."""
    stuffed = stuff(body)
    length = len(stuffed) + 2
    packet = HEADER + bytes([servo_id, length & 0xFF, length >> 8]) + stuffed
    crc = crc16(packet)
    return packet + bytes([crc & 0xFF, crc >> 8])


def status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    return build(servo_id, bytes([STATUS, error]) + params)


def instruction(servo_id: int, inst: int, params: bytes = b"") -> bytes:
    return build(servo_id, bytes([inst]) + params)


@dataclasses.dataclass(frozen=True)
class Packet:
    servo_id: int
    inst: int
    params: bytes
    crc_ok: bool

    @property
    def size(self) -> int:
        """Bytes on the wire (header 4, id, length 2, instruction, params, CRC 2; before stuffing)."""
        return 10 + len(self.params)


def parse(buffer: bytearray) -> Packet | None:
    """Take one packet off the front of ``buffer`` (consumed in place); None if incomplete.

    Bytes before a header are noise and are dropped, as a servo does on a shared bus.
    """
    while True:
        start = buffer.find(HEADER[:3])
        if start < 0:
            del buffer[: max(0, len(buffer) - 2)]
            return None
        if start:
            del buffer[:start]
        if len(buffer) < 7:
            return None
        if buffer[3] != 0x00:  # FF FF FD FD is stuffing, not a header
            del buffer[:1]
            continue
        length = buffer[5] | (buffer[6] << 8)
        if length < 3 or length > 1024:
            del buffer[:1]
            continue
        total = 7 + length
        if len(buffer) < total:
            return None
        raw = bytes(buffer[:total])
        del buffer[:total]
        crc_ok = crc16(raw[:-2]) == (raw[-2] | (raw[-1] << 8))
        body = unstuff(raw[7:-2])
        return Packet(raw[4], body[0], body[1:], crc_ok)
