"""The backend plugin contract (DESIGN, "Plugins").

The scheduler opens each backend with its target spec and the session, then calls ``send`` once
per frame from that backend's own worker thread, and ``close`` exactly once at the end, also after
an error or Ctrl-C. ``close`` must leave every output complete (files renamed into place, servos
eased to neutral with torque off). ``health`` may be called from another thread at any time.
A backend declares its options once, as the dataclass named by its ``Options`` attribute
(``convodrive.plugins.options``); the constructor parses whatever it is given into that, so
``self.options`` is always typed and checked.
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


class Backend(abc.ABC):
    """A body that consumes target frames. Subclasses set the class attributes below."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    realtime: ClassVar[bool] = False
    """True for hardware and live windows: paced by the wall clock. False for files."""
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
    def send(self, frame: TargetFrame) -> None:
        """Apply one frame. Must not block for long in real time; raise on a fault."""

    def close(self) -> None:  # noqa: B027 (optional hook; most backends have nothing to finish)
        """Finish every output. Called once, even after errors."""

    def health(self) -> dict[str, Any]:
        """A JSON-able snapshot: at least ``{"status": "ok" | "degraded" | "failed"}``."""
        return {"status": "ok"}

    def report(self) -> dict[str, Any]:
        """A JSON-able summary for the run report, called after ``close``: outputs, errors, metrics."""
        return {}

    def outputs(self) -> list[Path]:
        """Files this backend wrote, for the CLI to print."""
        return []
