"""What the UDP backends (``livelink``, ``osc``) share: one socket to one receiver, and its counts."""

from __future__ import annotations

import socket
from typing import Any, ClassVar

from convodrive.backends.base import Backend, Session
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plumbing.errors import UserError


class UdpSender:
    """Datagrams to ``host:port``; an unknown host is a ``UserError`` naming the backend.

    The socket is connected, so the system tells us when the receiver's port is closed (a refused
    datagram comes back as ``ConnectionRefusedError`` on the next send). Each frame is still sent:
    after a refusal the datagram goes out again at once, so a receiver that starts late gets it,
    and ``send`` then raises, so the run counts a frame nobody was there to take as an error.
    """

    def __init__(self, backend: str, host: str, port: int) -> None:
        try:
            family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        except socket.gaierror as exc:
            raise UserError(f"backend {backend}: option 'host': cannot resolve {host!r} ({exc.strerror})") from None
        self.destination = f"{host}:{port}"
        self._socket = socket.socket(family, kind, proto)
        try:
            self._socket.connect(address)
        except OSError:
            self._socket.close()
            raise
        self.sent = 0
        self.bytes = 0

    def send(self, packet: bytes) -> None:
        try:
            self._socket.send(packet)
        except ConnectionRefusedError:  # the previous datagram was refused; this one was not sent
            self._socket.send(packet)
            raise ConnectionRefusedError(f"nothing listens at {self.destination} (the datagram was refused)") from None
        self.sent += 1
        self.bytes += len(packet)

    def close(self) -> None:
        self._socket.close()

    def report(self, unit: str) -> dict[str, Any]:
        """For the backend's report: where to, and how many datagrams (``unit``) and bytes went."""
        return {"destination": self.destination, unit: self.sent, "bytes": self.bytes}


class UdpBackend(Backend):
    """A backend that sends each frame as one datagram to its options' ``host:port``: a subclass
    says how a frame becomes bytes (``datagram``) and what its report calls one (``unit``)."""

    unit: ClassVar[str] = "datagrams"
    realtime = True
    _udp: UdpSender | None = None

    def datagram(self, frame: TargetFrame) -> bytes:
        raise NotImplementedError

    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        options: Any = self.options
        self._udp = UdpSender(self.name, options.host, options.port)

    def send(self, frame: TargetFrame) -> None:
        assert self._udp is not None
        self._udp.send(self.datagram(frame))

    def close(self) -> None:
        if self._udp is not None:
            self._udp.close()

    def report(self) -> dict[str, Any]:
        return self._udp.report(self.unit) if self._udp is not None else {}
