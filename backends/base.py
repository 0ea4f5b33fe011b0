"""The backend plugin contract (DESIGN, "Plugins").

The scheduler opens each backend with its target spec and the session, then calls ``send`` once
per frame from that backend's own worker thread, and ``close`` exactly once at the end, also after
an error or Ctrl-C. ``close`` must leave every output complete (files renamed into place, servos
eased to neutral with torque off). ``health`` may be called from another thread at any time,
and so may ``hurry`` (the user's second Ctrl-C).
A backend declares its options once, as the dataclass named by its ``Options`` attribute
(``convodrive.plugins.options``); the constructor parses whatever it is given into that, so
``self.options`` is always typed and checked.

A backend whose work is heavy (rendering, physics) declares ``may_run_in_process``; in a real-time
run the pipeline then runs it in a child process of its own (``convodrive.scheduler.process``), so
its CPU time and its long C calls cannot delay the clock.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from convodrive import FPS
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, coerce_options, option


@dataclasses.dataclass(frozen=True)
class Session:
    """What every backend may know about the run it is part of."""

    out_dir: Path
    audio_path: Path | None = None
    """The user's audio file, for muxing into videos; None when driven without a file."""
    duration: float | None = None
    """Seconds of audio, when known in advance (file input)."""
    num_frames: int | None = None
    fps: float = FPS
    offline: bool = True
    """Offline: a simulated clock, every frame delivered; real time: wall clock, frames may drop."""
    seed: int = 0
    num_samples: int = 1


@dataclasses.dataclass(frozen=True)
class RobotOptions(PluginOptions):
    """Options every backend that drives a robot profile takes (read by the pipeline)."""

    profile: str | None = option(
        None,
        help="Robot profile to drive (a YAML path or a bundled name); default: the run config when it "
        "is a profile, else the backend's own",
    )


class BackendFailed(Exception):
    """Raised by ``send`` when the backend can take no more frames (its process died): the scheduler
    marks it failed at once instead of retrying."""


class Backend(abc.ABC):
    """A body that consumes target frames. Subclasses set the class attributes below."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    realtime: ClassVar[bool] = False
    """True for hardware and live windows: paced by the wall clock. False for files."""
    hardware: ClassVar[bool] = False
    """True for physical devices (servo heads): a run in which one fails exits non-zero."""
    may_run_in_process: ClassVar[bool] = False
    """True when the backend may run in a child process of its own: it shares nothing with the run
    but its options, spec, session and frames (all picklable); whatever it holds (a GL context, a
    serial port) it opens and closes there; its results are files and the JSON of ``health`` and
    ``report``."""
    light: ClassVar[bool] = False
    """True when ``send`` does little work (well under a millisecond of CPU, no waiting on a
    device): in a real-time run its worker then shares the clock's real-time scheduling, below the
    clock (``convodrive.plumbing.priority.HelperPriority``)."""
    default_profile: ClassVar[str | None] = None
    """A robot profile under config/robots used when the run names none; None for canonical-only."""
    requires: ClassVar[tuple[str, ...]] = ()
    """Modules the backend imports only when it opens; a missing one makes the plugin unavailable."""
    extra: ClassVar[str] = ""
    """The pip extra of convodrive that installs ``requires``, for the error message."""
    Options: ClassVar[type[PluginOptions]] = PluginOptions
    """The dataclass of this backend's options (the base class: none). A backend with a
    ``default_profile`` derives it from ``RobotOptions``."""

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        self.options = coerce_options(self.Options, options, plugin=f"backend {self.name}")
        self.spec: TargetSpec = TargetSpec.empty()
        self.session: Session | None = None

    def open(self, spec: TargetSpec, session: Session) -> None:
        """Acquire resources. Raise ``UserError`` for a configuration mistake."""
        self.spec = spec
        self.session = session

    @abc.abstractmethod
    def send(self, frame: TargetFrame) -> float | None:
        """Apply one frame. Must not block for long in real time; raise on a fault.

        May return when (``time.monotonic()``) the frame left for its device, where that is not
        the moment ``send`` returns (a backend in a child process answers after a round trip); the
        run's latency figures then end there. None: when it returned."""

    def close(self) -> None:  # noqa: B027 (optional hook; most backends have nothing to finish)
        """Finish every output. Called once, even after errors."""

    def hurry(self) -> None:  # noqa: B027 (optional hook; only slow closes need it)
        """The user asked to stop now (a second Ctrl-C): make ``close`` quick and safe (servos cut
        torque instead of easing). Called from another thread; must return at once."""

    def health(self) -> dict[str, Any]:
        """A JSON-able snapshot: at least ``{"status": "ok" | "degraded" | "failed"}``, and when the
        status is not ok, ``"reason"``: one line a user can act on (no display, servo 4 lost)."""
        return {"status": "ok"}

    def report(self) -> dict[str, Any]:
        """A JSON-able summary for the run report, called after ``close``: outputs, errors, metrics."""
        return {}

    def outputs(self) -> list[Path]:
        """Files this backend wrote, for the CLI to print."""
        return []
