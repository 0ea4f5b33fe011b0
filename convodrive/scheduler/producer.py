"""The generator's thread: it runs ahead of the clock into a bounded buffer.

It also retargets: each frame leaves here as the finished target frames, one per route, so the
clock thread only waits and hands them out. Retargeters are stateful filters that must see every
frame once and in order, which this one thread guarantees.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from convodrive.motion.clip import MotionFrame
from convodrive.plumbing.priority import HelperPriority
from convodrive.scheduler.slots import END

FrameSource = Iterator[tuple[MotionFrame, ...]]
"""Yields, for each frame index in order, one MotionFrame per take."""

Prepare = Callable[[int, tuple[MotionFrame, ...]], Any]
"""Turns frame ``index``'s takes into what the clock hands out (the routes' target frames)."""


class Producer(threading.Thread):
    """Pulls frames from the generator, prepares them, and fills a bounded buffer; times both."""

    def __init__(self, source: FrameSource, prepare: Prepare, buffer_frames: int, paced: bool = False) -> None:
        super().__init__(name="generator", daemon=True)
        self.source = source
        self.prepare = prepare
        self.buffer: queue.Queue[Any] = queue.Queue(maxsize=buffer_frames)
        self.generator_seconds = 0.0
        self.prepare_seconds = 0.0
        self.error: BaseException | None = None
        self.stop_event = threading.Event()
        self.priority = HelperPriority(paced, "generator")
        """In a paced run, real-time scheduling below the clock while the generator keeps up: this
        thread holds the interpreter lock more than any other of the clock's process."""

    def run(self) -> None:
        try:
            with self.priority:
                self._produce()
        except BaseException as exc:  # handed to the clock thread, which re-raises it
            self.error = exc
        finally:
            self._put(END, force=True)

    def _produce(self) -> None:
        index = 0
        while not self.stop_event.is_set():
            start = time.perf_counter()
            try:
                takes = next(self.source)
            except StopIteration:
                return
            finally:
                self.generator_seconds += time.perf_counter() - start
            start = time.perf_counter()
            item = self.prepare(index, takes)
            self.prepare_seconds += time.perf_counter() - start
            self.priority.tick()
            self._put(item)
            index += 1

    def _put(self, item: Any, force: bool = False) -> None:
        while True:
            if self.stop_event.is_set() and not force:
                return
            try:
                self.buffer.put(item, timeout=0.05)
                return
            except queue.Full:
                if force and self.stop_event.is_set():
                    try:  # make room for the end marker: nobody reads the rest anyway
                        self.buffer.get_nowait()
                    except queue.Empty:
                        pass
