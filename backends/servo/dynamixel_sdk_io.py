"""The two places where ``dynamixel_sdk`` needed correcting: its packet handler trusted a status
packet shorter than the request (``CheckedPacketHandler`` refuses one as ``ShortReply``), and its
port spun a core waiting for bytes and assumed a 16 ms USB latency (``LatencyPort``)."""

from __future__ import annotations

import select

import dynamixel_sdk as sdk


class ShortReply(Exception):
    """A status packet with a valid checksum but less data than the request asked for."""


READ_WAIT_S = 0.001
"""Longest a read waits for bytes before the SDK looks at its packet timeout again."""
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


class LatencyPort(sdk.PortHandler):
    """The SDK's port with a configurable USB latency timer in its timeouts.

    The SDK assumes the FTDI default of 16 ms per direction; adapters set to 1 ms (or an emulator)
    can use shorter timeouts, which keeps a silent servo from costing ~34 ms per attempt.
    """

    def __init__(self, port_name: str, latency_ms: float) -> None:
        super().__init__(port_name)
        self.latency_ms = latency_ms

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 (SDK name)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * self.latency_ms + 2.0

    def readPort(self, length: int) -> bytes:  # noqa: N802 (SDK name)
        """What has arrived, waiting up to ``READ_WAIT_S`` for it when nothing has.

        The SDK calls this in a loop until its packet timeout, and the port never blocks, so the
        loop spun a core for the whole wait (up to 2 x latency_ms for a silent servo). Waiting in
        ``select`` returns as soon as a byte comes and leaves the CPU to others meanwhile.
        """
        data = self.ser.read(length)
        if data:
            return bytes(data)
        try:
            select.select([self.ser.fileno()], [], [], READ_WAIT_S)
        except ValueError as exc:  # the port was closed under us
            raise OSError(str(exc)) from None
        return bytes(self.ser.read(length))
