"""The link to Reachy Mini's daemon through the official SDK client (``-B reachy_mini.client=sdk``).

The same link as ``reachy.link.DaemonLink`` (its state, history, counters, reconnects), with the
client of PyPI's ``reachy-mini`` doing the talking: ``ReachyMini.set_target`` sends each frame,
and the client's own receive thread takes the state the daemon pushes; every message it takes is
also handed to the link (the one hook into the client's internals: ``client._dispatch``), so the
read-back history and the health come from the same messages either way.

The client is built with ``connection_mode="network"`` on the given host (never mDNS), the default
robot name (another name makes it browse mDNS), ``media_backend="no_media"`` and the daemon's
default automatic body yaw (its constructor sets that daemon-wide). ``reachy-mini`` pins
onnxruntime 1.27, websockets < 16 and huggingface-hub < 2, which this project's runtime is past, so
``scripts/setup.sh --dev`` installs it without its dependencies, then the few its client needs
(README, "Reachy Mini"); it works with the newer versions.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from convodrive.backends.reachy.link import OPEN_TIMEOUT_S, DaemonLink

POLL_S = 0.05
"""How often the link checks that the client's receive thread is still there."""


class SdkLink(DaemonLink):
    """``DaemonLink`` through ``reachy_mini.ReachyMini``."""

    def _connect(self) -> None:
        try:
            from reachy_mini import ReachyMini
        except ImportError as exc:
            raise OSError(
                f"the official client needs PyPI's reachy-mini and its client's dependencies ({exc}); "
                "scripts/setup.sh --dev installs them (README, 'Reachy Mini')"
            ) from None
        logging.getLogger("reachy_mini").setLevel(logging.WARNING)
        try:
            mini = ReachyMini(
                host=self.host,
                port=self.port,
                connection_mode="network",
                timeout=OPEN_TIMEOUT_S,
                media_backend="no_media",
                log_level="WARNING",
            )
        except (ConnectionError, TimeoutError) as exc:
            raise OSError(str(exc)) from None
        client = mini.client
        dispatch = client._dispatch

        def tap(message: Any) -> None:
            dispatch(message)
            if not self._stop.is_set():
                self._take(message.model_dump_json())

        client._dispatch = tap
        self._ws = mini
        self.connected.set()

    def _receive(self, mini: Any) -> None:
        """The client receives on its own thread; this one only notices when it has ended."""
        if not mini.client._recv_thread.is_alive():
            raise ConnectionError("the SDK client's connection closed")
        self._stop.wait(POLL_S)

    def _write(self, mini: Any, head: np.ndarray, body_yaw: float, antennas: tuple[float, float]) -> None:
        mini.set_target(head=head, antennas=[antennas[0], antennas[1]], body_yaw=body_yaw)

    @staticmethod
    def _shut(mini: Any) -> None:
        try:
            mini.__exit__(None, None, None)
        except Exception:  # noqa: BLE001 - closing a dead client
            pass
