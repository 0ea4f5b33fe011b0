"""Test doubles: backends that count, stall or fail like hardware does, and a neutral frame source.

The tests and the scheduler benchmark both use them; nothing shipped does.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from convodrive import FPS
from convodrive.backends.base import Backend, Session
from convodrive.motion.clip import MotionFrame
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, option
from convodrive.plumbing.atomic import write_text_atomic
from convodrive.plumbing.errors import UserError


@dataclasses.dataclass(frozen=True)
class DoubleOptions(PluginOptions):
    name: str = option("fast", help="Name in the run report")
    delay: float = option(0.2, low=0, high=60, help="Seconds a SlowBackend takes per frame")


class CountingBackend(Backend):
    """A fast backend that records which frame indices reached it, and when."""

    name = "fast"
    realtime = True
    light = True  # appending an index: a real-time run schedules its worker below the clock
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

    light = False

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


@dataclasses.dataclass(frozen=True)
class ProbeOptions(DoubleOptions):
    delay: float = option(0.0, low=0, high=60, help="Seconds each frame takes")
    fail_at: int | None = option(None, help="Raise OSError on this frame")
    die_at: int | None = option(None, help="The process kills itself with SIGKILL on this frame")
    close_error: str = option("", help="close() raises this, after finishing its output")
    open_user_error: str = option("", help="open() raises this as a UserError")
    hurry_file: str = option("", help="hurry() writes this file")


class ChildProbeBackend(CountingBackend):
    """Fails, crashes or stalls where its options say, and tells which process it ran in.
    ``close`` writes ``NAME_indices.txt`` into the session's folder, atomically, as its output."""

    Options = ProbeOptions
    options: ProbeOptions
    may_run_in_process = True

    def open(self, spec: TargetSpec, session: Session) -> None:
        if self.options.open_user_error:
            raise UserError(self.options.open_user_error)
        super().open(spec, session)
        self.output = session.out_dir / f"{self.name}_indices.txt"

    def send(self, frame: TargetFrame) -> None:
        if frame.index == self.options.die_at:
            os.kill(os.getpid(), signal.SIGKILL)
        if frame.index == self.options.fail_at:
            raise OSError("port vanished")
        time.sleep(self.options.delay)
        super().send(frame)

    def hurry(self) -> None:
        if self.options.hurry_file:
            Path(self.options.hurry_file).write_text("hurried")

    def close(self) -> None:
        super().close()
        if self.session is not None:
            write_text_atomic(self.output, " ".join(map(str, self.indices)))
        if self.options.close_error:
            raise RuntimeError(self.options.close_error)

    def health(self) -> dict[str, Any]:
        return {"status": "ok", "pid": os.getpid(), "frames": len(self.indices)}

    def report(self) -> dict[str, Any]:
        return {"pid": os.getpid(), "indices": self.indices, "closed": self.closed}

    def outputs(self) -> list[Path]:
        return [self.output] if self.output.exists() else []
