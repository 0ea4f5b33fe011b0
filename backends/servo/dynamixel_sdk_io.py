"""The two places where ``dynamixel_sdk`` needed correcting: its packet handler trusted a status
packet shorter than the request (``CheckedPacketHandler`` refuses one as ``ShortReply``), and its
port spun a core waiting for bytes and assumed a 16 ms USB latency (``serial_port.LatencyPort``)."""

from __future__ import annotations

import dynamixel_sdk as sdk

from convodrive.backends.servo import serial_port
from convodrive.backends.servo.serial_port import ShortReply

STATUS_OVERHEAD = 11
"""Bytes of a status packet around its data: header 4, id, length 2, instruction, error, CRC 2."""
PING_DATA = 3  # model number 2, firmware 1


class CheckedPacketHandler(sdk.Protocol2PacketHandler):  # type: ignore[misc]
    """The SDK's Protocol 2.0 handler, refusing a status packet with less data than was asked for."""

    def txRxPacket(self, port, txpacket):  # type: ignore[no-untyped-def]  # noqa: N802 (SDK name)
        rxpacket, result, error = super().txRxPacket(port, txpacket)
        if result == sdk.COMM_SUCCESS and rxpacket is not None:
            inst = txpacket[sdk.PKT_INSTRUCTION]
            if inst == sdk.INST_READ:
                wanted = sdk.DXL_MAKEWORD(txpacket[sdk.PKT_PARAMETER0 + 2], txpacket[sdk.PKT_PARAMETER0 + 3])
            else:
                wanted = PING_DATA if inst == sdk.INST_PING else 0
            if len(rxpacket) < STATUS_OVERHEAD + wanted:
                raise ShortReply(f"status packet of {len(rxpacket)} bytes, {STATUS_OVERHEAD + wanted} expected")
        return rxpacket, result, error


class LatencyPort(serial_port.LatencyPort, sdk.PortHandler):  # type: ignore[misc]
    """The SDK's port with a configurable USB latency timer and reads that do not spin."""
