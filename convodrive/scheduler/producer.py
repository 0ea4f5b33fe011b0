"""The generator's thread: it runs ahead of the clock into a bounded buffer, and times the generator."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator
from typing import Any

from convodrive.motion.clip import MotionFrame
from convodrive.scheduler.slots import END

FrameSource = Iterator[tuple[MotionFrame, ...]]
"""Yields, for each frame index in order, one MotionFrame per take."""


class Producer(threading.Thread):
    """Pulls frames from the generator into a bounded buffer and times the generator."""

    def __init__(self, source: FrameSource, buffer_frames: int) -> None:
        super().__init__(name="generator", daemon=True)
        self.source = source
        self.buffer: queue.Queue[Any] = queue.Queue(maxsize=buffer_frames)
        self.generator_seconds = 0.0
        self.error: BaseException | None = None
        self.stop_event = threading.Event()

    def run(self) -> None:
        try:
            while not self.stop_event.is_set():
                start = time.perf_counter()
                try:
                    takes = next(self.source)
                except StopIteration:
                    break
                finally:
                    self.generator_seconds += time.perf_counter() - start
                self._put(takes)
        except BaseException as exc:  # handed to the clock thread, which re-raises it
            self.error = exc
        finally:
            self._put(END, force=True)

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
