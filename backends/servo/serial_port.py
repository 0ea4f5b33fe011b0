"""What every serial servo bus shares: the port-lost signal, one line for a port that will not open,
and the latency-aware, non-spinning port reads both servo SDKs lacked (``LatencyPort``)."""

from __future__ import annotations

import re
import select
from typing import Any

from convodrive.plumbing.errors import UserError


class PortLost(Exception):
    """The serial port failed underneath us (unplugged, closed); the backend must reconnect."""


class ShortReply(Exception):
    """A status packet with a valid checksum but less data than the request asked for."""


def open_error(port: str, exc: Exception) -> UserError:
    """One line saying why a serial port would not open."""
    args = exc.args
    errno = getattr(exc, "errno", None) or (args[0] if args and isinstance(args[0], int) else None)
    nested = re.search(r"\((\d+), '", str(exc))  # pyserial wraps termios errors in its message
    errno = errno or (int(nested.group(1)) if nested else None)
    reason = {
        2: "no such port",
        13: "permission denied (is your user in the dialout group?)",
        16: "port is busy (another program has it open)",
        25: "not a serial port",
    }.get(errno or 0)
    if reason is None:
        reason = str(args[-1] if args and isinstance(args[-1], str) else exc).split(": ")[-1]
    return UserError(f"{port}: cannot open serial port ({reason})")


READ_WAIT_S = 0.001
"""Longest a read waits for bytes before the SDK looks at its packet timeout again."""
LATE_READ_MS = 1000.0
"""How long past its timeout a status packet whose bytes already wait in the port is still read."""


class LatencyPort:
    """Mixed in before an SDK's ``PortHandler`` (both SDKs share its interface): a configurable
    USB latency timer in its timeouts, and reads that wait instead of spinning.

    The SDKs assume the FTDI default of 16 ms per direction; adapters set to 1 ms (or an emulator)
    can use shorter timeouts, which keeps a silent servo from costing ~34 ms per attempt.
    """

    ser: Any
    tx_time_per_byte: float
    packet_start_time: float
    packet_timeout: float
    getCurrentTime: Any  # noqa: N815 (the SDK's port gives it)

    def __init__(self, port_name: str, latency_ms: float) -> None:
        super().__init__(port_name)  # type: ignore[call-arg]
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

    def isPacketTimeout(self) -> bool:  # noqa: N802 (SDK name)
        """The SDK's timeout, but not while bytes wait in the port.

        The SDK reads, then looks at the clock. On a loaded machine the OS can preempt the reader
        between an empty read and that look for longer than the timeout: the reply came on time
        and waits in the port, and the SDK would call it lost (and the next request's flush would
        drop it). Waiting bytes are read first, up to ``LATE_READ_MS`` past the timeout, so a
        stream of noise still ends."""
        elapsed = self.getTimeSinceStart()
        if self.packet_timeout and elapsed <= self.packet_timeout + LATE_READ_MS and self._bytes_waiting():
            return False
        return bool(super().isPacketTimeout())  # type: ignore[misc]

    def _bytes_waiting(self) -> bool:
        try:
            return bool(self.ser.in_waiting)
        except (OSError, ValueError, AttributeError):  # closed, or no port yet
            return False
