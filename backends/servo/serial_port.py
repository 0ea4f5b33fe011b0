"""What every serial servo bus shares: the port-lost signal and one line for a port that will not open."""

from __future__ import annotations

import re

from convodrive.plumbing.errors import UserError


class PortLost(Exception):
    """The serial port failed underneath us (unplugged, closed); the backend must reconnect."""


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
