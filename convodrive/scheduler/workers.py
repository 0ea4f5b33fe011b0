"""One worker thread per backend: it sends what arrives in its slot and closes the backend at the end."""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from convodrive.backends.base import BackendFailed
from convodrive.motion.targets import TargetFrame
from convodrive.plumbing.errors import error_line
from convodrive.plumbing.priority import HelperPriority
from convodrive.plumbing.stats import Histogram
from convodrive.scheduler.route import Route
from convodrive.scheduler.slots import END, BlockingSlot, DropOldestSlot

log = logging.getLogger(__name__)

OnSent = Callable[[str, TargetFrame, float], None]
"""Called from a backend's worker after each ``send`` returns: backend name, the frame, and
``time.monotonic()`` then (a live run turns it into capture-to-body latency)."""

MAX_CONSECUTIVE_ERRORS = 90
"""A backend that raised on 3 s of consecutive frames is marked failed and no longer called."""


@dataclasses.dataclass
class BackendStats:
    name: str
    sent: int = 0
    dropped: int = 0
    errors: int = 0
    last_error: str = ""
    failed: bool = False
    close_error: str = ""
    send_seconds: list[float] = dataclasses.field(default_factory=list)
    dispatch_to_sent_ms: Histogram = dataclasses.field(default_factory=Histogram)
    """Real-time runs: from the clock dispatching a frame to ``send`` returning (queue + send)."""
    health_events: list[dict[str, Any]] = dataclasses.field(default_factory=list)


class BackendWorker(threading.Thread):
    """Runs one backend: sends what arrives in its slot, and closes it when the run ends."""

    def __init__(self, route: Route, paced: bool, now: Callable[[], float], on_sent: OnSent | None = None) -> None:
        super().__init__(name=f"backend-{route.backend.name}", daemon=True)
        self.route = route
        self.slot: DropOldestSlot | BlockingSlot
        if not paced:
            self.slot = BlockingSlot()
        elif route.backend.realtime:
            self.slot = DropOldestSlot(DropOldestSlot.LATEST_CAPACITY)
        else:
            self.slot = DropOldestSlot(DropOldestSlot.BACKLOG_CAPACITY)
        self.stats = BackendStats(route.backend.name)
        self.priority = HelperPriority(paced and route.backend.light, f"backend {route.backend.name}")
        """Real-time scheduling below the clock while frames flow, for a light backend's worker."""
        self._now = now
        self._on_sent = on_sent
        self._last_status = "ok"
        self._frame = -1
        """The index of the frame last handed to the backend, for the log."""

    def run(self) -> None:
        try:
            with self.priority:  # closing (files written, servos eased) runs at ordinary priority
                self._send_frames()
        finally:
            self.close_backend()

    def _send_frames(self) -> None:
        backend = self.route.backend
        consecutive = 0
        while True:
            item = self.slot.get()
            if item is END:
                return
            if self.stats.failed:
                self.stats.dropped += 1
                continue
            start = time.perf_counter()
            self._frame = item.index
            try:
                left = backend.send(item)
                consecutive = 0
                self.stats.sent += 1
                self._sent(item, left)
            except Exception as exc:  # a backend fault degrades this backend only
                consecutive += 1
                self.stats.errors += 1
                self.stats.last_error = error_line(exc)
                if consecutive == 1:  # the first of a run of errors; the report counts them all
                    log.warning("%s: frame %d: %s", backend.name, item.index, self.stats.last_error)
                if consecutive >= MAX_CONSECUTIVE_ERRORS or isinstance(exc, BackendFailed):
                    self.stats.failed = True
                    self._event("failed", self.stats.last_error)
            finally:
                spent = time.perf_counter() - start
                self.stats.send_seconds.append(spent)
                self.priority.tick()
            self._watch_health()

    def _sent(self, frame: TargetFrame, left: float | None) -> None:
        if not frame.dispatched:
            return
        done = time.monotonic() if left is None else left
        self.stats.dispatch_to_sent_ms.add(1000.0 * (done - frame.dispatched))
        if self._on_sent is not None:
            self._on_sent(self.stats.name, frame, done)

    def hurry(self) -> None:
        """Stop at once: drop the frames still waiting, and let the backend cut its close short."""
        self.slot.discard()
        try:
            self.route.backend.hurry()
        except Exception as exc:
            self._event("hurry-error", error_line(exc))

    def close_backend(self) -> None:
        try:
            self.route.backend.close()
        except Exception as exc:
            self.stats.close_error = error_line(exc)
            self._event("close-error", self.stats.close_error)
        self.stats.dropped += self.slot.dropped

    def _watch_health(self) -> None:
        if self.stats.sent % 30:
            return
        try:
            status = str(self.route.backend.health().get("status", "ok"))
        except Exception as exc:
            status = f"health-error: {exc}"
        if status != self._last_status:
            self._event(status, "")
            self._last_status = status

    def _event(self, status: str, detail: str) -> None:
        self.stats.health_events.append({"time": round(self._now(), 3), "status": status, "detail": detail})
        level = logging.INFO if status == "ok" else logging.ERROR if status == "failed" else logging.WARNING
        where = f"after frame {self._frame}" if self._frame >= 0 else "at the end"
        log.log(level, "%s: %s %s%s", self.route.backend.name, status, where, f": {detail}" if detail else "")
