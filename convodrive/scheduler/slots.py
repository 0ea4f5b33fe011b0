"""Mailboxes between the clock and a backend's worker.

In a paced run the clock must never wait for a backend, so it puts frames into a drop-oldest slot;
in an unpaced (simulated) run every frame must arrive, so it puts them into a small blocking queue.
"""

from __future__ import annotations

import collections
import queue
import threading
from typing import Any

END = object()
"""What ``get`` returns once a slot is closed and empty: the end of the run."""


class DropOldestSlot:
    """A mailbox that never blocks the clock: past ``capacity`` unread frames the oldest go.

    Two sizes serve two kinds of backend in a real-time run. A real-time backend (hardware, a live
    window) gets ``LATEST_CAPACITY``: a slow one skips to the newest frames, never more than 100 ms
    behind; 3 rather than 1 lets a backend that keeps up absorb the frames the clock sends back to
    back after the OS held the process past a deadline (a stall of up to 100 ms). A file backend (recorder, video) gets
    ``BACKLOG_CAPACITY``: it receives every frame, late if it must, without slowing the clock.
    ``close`` lets the reader take what is left, then the end of the run.
    """

    LATEST_CAPACITY = 3
    BACKLOG_CAPACITY = 9000  # 5 minutes at 30 fps

    def __init__(self, capacity: int) -> None:
        self._cond = threading.Condition()
        self._items: collections.deque[Any] = collections.deque()
        self._capacity = capacity
        self._closed = False
        self.dropped = 0

    def put(self, item: Any) -> None:
        with self._cond:
            self._items.append(item)
            if len(self._items) > self._capacity:
                self._items.popleft()
                self.dropped += 1
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()

    def get(self) -> Any:
        with self._cond:
            while not self._items and not self._closed:
                self._cond.wait()
            return self._items.popleft() if self._items else END

    def pending(self) -> int:
        """Frames waiting to be read."""
        with self._cond:
            return len(self._items)

    def discard(self) -> None:
        """Drop every waiting frame (the user asked to stop at once); they count as dropped."""
        with self._cond:
            self.dropped += len(self._items)
            self._items.clear()


class BlockingSlot:
    """A small FIFO for offline runs: every frame is delivered; a slow backend slows the run."""

    def __init__(self, size: int = 8) -> None:
        self._q: queue.Queue[Any] = queue.Queue(maxsize=size)
        self.dropped = 0

    def put(self, item: Any) -> None:
        self._q.put(item)

    def close(self) -> None:
        self._q.put(END)

    def get(self) -> Any:
        return self._q.get()

    def pending(self) -> int:
        return self._q.qsize()

    def discard(self) -> None:
        """Nothing to drop: at most ``size`` frames wait here, and the end marker must stay."""
