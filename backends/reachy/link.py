"""The link to Reachy Mini's daemon: its SDK WebSocket (``/ws/sdk``), spoken directly.

The official SDK client (``reachy_mini.ReachyMini``) is optional (``reachy.sdk_link``): its
package pins onnxruntime 1.27, websockets < 16 and huggingface-hub < 2, which this project's
runtime is past, and brings PyGObject (built from source) and zeroconf for its client alone; its
``set_target`` is one JSON message on this socket. So by default the backend speaks the same
protocol (``reachy_mini/io/protocol.py``): ``set_full_target`` out, one per frame, and the state
the daemon pushes in (``joint_positions`` and ``head_pose`` at 50 Hz, ``daemon_status`` at 1 Hz).

A reader thread keeps the newest state and a history of read-backs for the tracking figures; a
closed socket is a disconnect, retried with back-off, never an exception out of ``send``.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from typing import Any

import numpy as np

from convodrive.backends.reachy.pose import BODY, FIELDS, head_from_matrix

log = logging.getLogger(__name__)

HISTORY = 30 * 60 * 50
"""Read-backs kept (half an hour at 50 Hz) for the lag and tracking figures."""
OPEN_TIMEOUT_S = 3.0


class DaemonLink:
    """One WebSocket to the daemon, a reader thread, and the newest read-back."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.uri = f"ws://{host}:{port}/ws/sdk"
        self._ws: Any = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._head: np.ndarray | None = None  # x, y, z, roll, pitch, yaw
        self._joints: tuple[float, float, float] | None = None  # body yaw, antenna right, left
        self.readback: collections.deque[tuple[float, np.ndarray]] = collections.deque(maxlen=HISTORY)
        self.last_state_at = 0.0
        self.status: dict[str, Any] = {}
        self.disconnects = 0
        self.reconnects = 0
        self.sent = 0
        self.unsent = 0
        self.connected = threading.Event()

    # ------------------------------------------------------------------ connection
    def open(self) -> None:
        """Connect and wait for the first full state; raises OSError when the daemon is not there."""
        self._connect()
        self._thread = threading.Thread(target=self._read, name="reachy-link", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + OPEN_TIMEOUT_S
        while self.latest() is None:
            if time.monotonic() > deadline:
                self.close()
                raise OSError(f"{self.uri}: connected, but the daemon sent no state in {OPEN_TIMEOUT_S:g} s")
            time.sleep(0.01)

    def _connect(self) -> None:
        from websockets.sync.client import connect

        # Entered as a context manager (websockets 17 asks for that); ``_lost`` and ``close`` exit it.
        self._ws = connect(self.uri, compression=None, open_timeout=OPEN_TIMEOUT_S, max_queue=None).__enter__()
        self.connected.set()

    def _read(self) -> None:
        backoff = 0.2
        while not self._stop.is_set():
            ws = self._ws
            if ws is None:
                if self._stop.wait(backoff):
                    return
                try:
                    self._connect()
                    self.reconnects += 1
                    backoff = 0.2
                    log.info("reachy_mini: reconnected to %s", self.uri)
                except (OSError, TimeoutError, Exception) as exc:  # noqa: BLE001 - any failure: retry later
                    backoff = min(2.0, backoff * 2)
                    log.debug("reachy_mini: reconnect failed: %s", exc)
                continue
            try:
                self._receive(ws)
            except Exception as exc:  # noqa: BLE001 - ConnectionClosed, OSError: both a disconnect
                if self._stop.is_set():
                    return
                self._lost(str(exc) or type(exc).__name__)

    def _receive(self, ws: Any) -> None:
        """Take one state message; raise when the connection is gone."""
        self._take(ws.recv())

    def _lost(self, detail: str) -> None:
        with self._lock:
            if self._ws is None:
                return
            self._shut(self._ws)
            self._ws = None
            self.connected.clear()
            self.disconnects += 1
        log.warning("reachy_mini: lost the daemon at %s: %s", self.uri, detail)

    def _take(self, message: str | bytes) -> None:
        try:
            data = json.loads(message)
            kind = data.get("type")
            now = time.monotonic()
            if kind == "head_pose":
                self._head = head_from_matrix(np.array(data["head_pose"], dtype=float))
            elif kind == "joint_positions":
                body = float(data["head_joint_positions"][0])
                right, left = (float(v) for v in data["antennas_joint_positions"])
                self._joints = (body, right, left)
            elif kind == "daemon_status":
                self.status = data
                return
            else:
                return
        except (ValueError, KeyError, TypeError, IndexError) as exc:
            log.debug("reachy_mini: unreadable state message: %s", exc)
            return
        state = self.latest()
        if state is not None:
            self.last_state_at = now
            self.readback.append((now, state))

    # ------------------------------------------------------------------ use
    def latest(self) -> np.ndarray | None:
        """The newest read-back as a command vector (``pose.FIELDS``), None before the first."""
        head, joints = self._head, self._joints
        if head is None or joints is None:
            return None
        out = np.empty(len(FIELDS))
        out[:6] = head
        out[BODY:] = joints
        return out

    def send_target(self, head: np.ndarray, body_yaw: float, antennas: tuple[float, float]) -> float | None:
        """One ``set_full_target``; returns when it left (``time.monotonic()``), None when unsent."""
        with self._lock:
            ws = self._ws
            if ws is None:
                self.unsent += 1
                return None
            try:
                self._write(ws, head, body_yaw, antennas)
            except Exception as exc:  # noqa: BLE001 - a broken socket is a disconnect, not a crash
                self.unsent += 1
                detail = str(exc) or type(exc).__name__
                ws = None
        if ws is None:
            self._lost(detail)
            return None
        self.sent += 1
        return time.monotonic()

    def _write(self, ws: Any, head: np.ndarray, body_yaw: float, antennas: tuple[float, float]) -> None:
        ws.send(
            json.dumps(
                {
                    "type": "set_full_target",
                    "head": [float(v) for v in head.ravel()],
                    "antennas": [float(antennas[0]), float(antennas[1])],
                    "body_yaw": float(body_yaw),
                }
            )
        )

    @staticmethod
    def _shut(ws: Any) -> None:
        try:
            ws.close()
        except Exception:  # noqa: BLE001 - closing a dead socket
            pass

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            ws, self._ws = self._ws, None
        if ws is not None:
            self._shut(ws)
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.connected.clear()
