"""Test doubles: backends that count, stall or fail like hardware does, and a neutral frame source.

The tests and the scheduler benchmark both use them; nothing shipped does.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Mapping
from typing import Any

from convodrive import FPS
from convodrive.backends.base import Backend
from convodrive.motion.clip import MotionFrame
from convodrive.motion.targets import TargetFrame
from convodrive.plugins.options import PluginOptions, option


@dataclasses.dataclass(frozen=True)
class DoubleOptions(PluginOptions):
    name: str = option("fast", help="Name in the run report")
    delay: float = option(0.2, low=0, high=60, help="Seconds a SlowBackend takes per frame")


class CountingBackend(Backend):
    """A fast backend that records which frame indices reached it, and when."""

    name = "fast"
    realtime = True
    Options = DoubleOptions
    options: DoubleOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.name = self.options.name
        self.indices: list[int] = []
        self.closed = False

    def send(self, frame: TargetFrame) -> None:
        self.indices.append(frame.index)

    def close(self) -> None:
        self.closed = True


class SlowBackend(CountingBackend):
    """Takes ``delay`` seconds per frame, like a congested serial bus."""

    def send(self, frame: TargetFrame) -> None:
        time.sleep(self.options.delay)
        super().send(frame)


class FailingBackend(CountingBackend):
    """Raises on every frame, like a servo head whose port vanished."""

    def send(self, frame: TargetFrame) -> None:
        raise OSError("port vanished")


def neutral_frames(count: int) -> Iterator[tuple[MotionFrame, ...]]:
    frame = MotionFrame.neutral()
    for i in range(count):
        yield (MotionFrame(i / FPS, frame.pose, frame.translation, frame.face, frame.vad),)
