"""A byte-level serial device on a pseudo-terminal, served from a thread.

The emulators sit on the master side of a pty, so the real serial stack (pyserial, the official
dynamixel-sdk) opens the slave path exactly as it would open /dev/ttyUSB0. With ``link`` the
device also gets a stable symlink, like /dev/serial/by-id/..., which lets a test unplug the port
(the pty closes, the link vanishes) and plug it back in under the same name.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

from convodrive.plumbing.errors import UserError, os_reason
from convodrive.plumbing.priority import EMULATOR_FIFO_PRIORITY, HelperPriority


def check_link(link: Path) -> None:
    """The link's folder must exist, and the link must not replace a file that is not a link."""
    if not link.parent.is_dir():
        raise UserError(f"--link {link}: no such folder {link.parent}")
    if link.exists() and not link.is_symlink():
        raise UserError(f"--link {link}: a file is already there (the link would replace it)")


class PtyServer:
    """Calls ``on_bytes(data)`` for every chunk the client writes; ``send`` answers it."""

    def __init__(
        self, on_bytes: Callable[[bytes], None], link: str | os.PathLike[str] | None = None, name: str = "pty-server"
    ) -> None:
        self._on_bytes = on_bytes
        self._link = Path(link) if link else None
        self._name = name
        self._lock = threading.Lock()
        self._master = -1
        self._slave = -1
        self._slave_path = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()
        self._timers: list[threading.Timer] = []

    # ----------------------------------------------------------------- lifecycle
    @property
    def port(self) -> str:
        """The path a client opens: the stable link if one was asked for, else the pty slave."""
        return str(self._link) if self._link else self._slave_path

    @property
    def connected(self) -> bool:
        return self._master >= 0

    def start(self) -> PtyServer:
        """Open the pty (and its link); a link that cannot be made is a ``UserError``."""
        if self._link:
            check_link(self._link)
        try:
            self._open_pty()
        except OSError as exc:
            self._close_pty()
            raise UserError(f"--link {self._link}: cannot make the link ({os_reason(exc)})") from None
        self._thread = threading.Thread(target=self._serve, name=self._name, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        for timer in self._timers:
            timer.cancel()
        os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._close_pty()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def unplug(self, seconds: float | None = None) -> None:
        """The port disappears (master closed, link removed); it comes back after ``seconds``."""
        self._close_pty()
        os.write(self._wake_w, b"x")
        if seconds is not None:
            self.after(seconds, self.replug)

    def replug(self) -> None:
        if not self._stop.is_set() and not self.connected:
            self._open_pty()
            os.write(self._wake_w, b"x")

    def after(self, seconds: float, action: Callable[[], None]) -> None:
        """Run ``action`` later on a timer thread (fault schedules)."""
        timer = threading.Timer(seconds, action)
        timer.daemon = True
        self._timers.append(timer)
        timer.start()

    # ----------------------------------------------------------------- I/O
    def send(self, data: bytes) -> None:
        with self._lock:
            fd = self._master
        if fd < 0:
            return
        try:
            os.write(fd, data)
        except OSError:
            pass  # the client went away mid-reply; a real device would not notice either

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass through untouched
        path = os.ttyname(slave)
        with self._lock:
            self._master, self._slave, self._slave_path = master, slave, path
        if self._link:
            tmp = self._link.with_name(f".{self._link.name}.{os.getpid()}.tmp")
            tmp.unlink(missing_ok=True)
            os.symlink(path, tmp)
            os.replace(tmp, self._link)

    def _close_pty(self) -> None:
        with self._lock:
            master, slave = self._master, self._slave
            self._master = self._slave = -1
        if self._link:
            self._link.unlink(missing_ok=True)
        for fd in (master, slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass

    def _serve(self) -> None:
        # It stands for a device, which does not share the driver's CPU: it answers like one, on
        # time, above the driver's real-time threads (while its work stays a small share of a core).
        with HelperPriority(True, self._name, priority=EMULATOR_FIFO_PRIORITY) as realtime:
            self._serve_until_stopped(realtime)

    def _serve_until_stopped(self, realtime: HelperPriority) -> None:
        while not self._stop.is_set():
            with self._lock:
                fd = self._master
            watch = [self._wake_r] + ([fd] if fd >= 0 else [])
            try:
                ready, _, _ = select.select(watch, [], [], 0.1)
            except (OSError, ValueError):
                time.sleep(0.01)
                continue
            if self._wake_r in ready:
                os.read(self._wake_r, 64)
            if fd >= 0 and fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    data = b""
                if data:
                    self._on_bytes(data)
                    realtime.tick()


class PtyDevice:
    """Base of the emulators: a device that answers bytes on its own ``PtyServer``.

    Subclasses create ``self._server`` in their ``__init__`` with their ``_on_bytes`` handler; this
    gives them the port path, start/stop, and use as a context manager (started if not yet).
    """

    _server: PtyServer

    @property
    def port(self) -> str:
        return self._server.port

    def start(self) -> PtyDevice:
        self._server.start()
        return self

    def stop(self) -> None:
        self._server.stop()

    def __enter__(self) -> PtyDevice:
        return self if self._server.connected else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
