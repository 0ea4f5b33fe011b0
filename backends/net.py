"""What the network backends (``livelink``, ``osc``, ``stream``) share: resolving where to send."""

from __future__ import annotations

import socket
from typing import Any

from convodrive.plumbing.errors import UserError


def open_udp(backend: str, host: str, port: int) -> tuple[socket.socket, tuple[Any, ...]]:
    """A UDP socket and the resolved address to send to (an unknown host is a ``UserError``)."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
    except socket.gaierror as exc:
        raise UserError(f"backend {backend}: option 'host': cannot resolve {host!r} ({exc.strerror})") from None
    return socket.socket(family, kind, proto), address
