"""Feetech (SCS protocol) framing written from the protocol description, for the emulator.

The emulator does not reuse ``scservo_sdk``'s framing, or a shared bug would pass unnoticed.
Instruction: ``FF FF | ID | LEN | INST | params | CHK``; status: ``FF FF | ID | LEN | ERR |
params | CHK``. LEN counts INST (or ERR), the params and the checksum; the checksum is the
inverted low byte of the sum of ID, LEN, INST/ERR and the params. No byte stuffing.
"""

from __future__ import annotations

import dataclasses

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
PING, READ, WRITE, REG_WRITE, ACTION, RESET = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
SYNC_READ, SYNC_WRITE = 0x82, 0x83
MAX_LENGTH = 250


def checksum(body: bytes | bytearray) -> int:
    """``~(ID + LEN + INST + params) & 0xFF``."""
    return ~sum(body) & 0xFF


@dataclasses.dataclass(frozen=True)
class Packet:
    servo_id: int
    inst: int
    params: bytes
    checksum_ok: bool

    @property
    def size(self) -> int:
        return 6 + len(self.params)


def parse(buffer: bytearray) -> Packet | None:
    """Take the first whole packet off ``buffer`` (dropping noise before it); None until one is complete."""
    while True:
        start = buffer.find(HEADER)
        if start < 0:
            del buffer[: max(0, len(buffer) - 1)]  # keep a trailing FF: it may start a header
            return None
        del buffer[:start]
        if len(buffer) < 4:
            return None
        length = buffer[3]
        if buffer[2] > BROADCAST_ID or not 2 <= length <= MAX_LENGTH:
            del buffer[:1]  # not a header after all (an FF FF inside noise)
            continue
        if len(buffer) < 4 + length:
            return None
        raw = bytes(buffer[: 4 + length])
        del buffer[: 4 + length]
        return Packet(raw[2], raw[4], raw[5:-1], checksum(raw[2:-1]) == raw[-1])


def instruction(servo_id: int, inst: int, params: bytes = b"") -> bytes:
    body = bytes([servo_id, len(params) + 2, inst]) + params
    return HEADER + body + bytes([checksum(body)])


def status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet; the same framing as an instruction, with the error byte in INST's place."""
    return instruction(servo_id, error, params)
