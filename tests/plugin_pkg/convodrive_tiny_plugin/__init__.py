"""A plugin that lives outside convodrive: it nods and logs the frames it receives.

Each plugin declares its options once, as a dataclass named by its ``Options`` attribute; the base
classes parse ``-G``/``-B``/YAML values into it, and ``convodrive plugins tiny_nod`` lists them.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from convodrive.audio.source import ANALYSIS_RATE, motion_frames_for
from convodrive.backends.base import Backend
from convodrive.generators.base import Generator
from convodrive.motion.clip import MotionFrame
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.plugins.options import PluginOptions, check_file_name, option
from convodrive.plumbing.atomic import write_text_atomic


@dataclasses.dataclass(frozen=True)
class NodOptions(PluginOptions):
    amplitude: float = option(0.2, low=0.0, high=0.5, help="Head pitch of a nod, radians")
    rate_hz: float = option(1.0, low=0.1, high=5.0, help="Nods per second")


class NodGenerator(Generator):
    name = "tiny_nod"
    description = "nods the head once a second, whatever is said (plugin test)"
    Options = NodOptions
    options: NodOptions

    def stream(self, chunks, seed=0):
        samples = 0
        emitted = 0
        for chunk in chunks:
            samples += len(chunk)
            due = motion_frames_for(samples / ANALYSIS_RATE) if chunk.final else int(samples / ANALYSIS_RATE * 30)
            while emitted < due:
                frame = MotionFrame.neutral(emitted / 30)
                phase = 2 * math.pi * self.options.rate_hz * emitted / 30
                frame.pose[JOINT_INDEX["head"], 0] = self.options.amplitude * math.sin(phase)
                yield frame
                emitted += 1


@dataclasses.dataclass(frozen=True)
class LogOptions(PluginOptions):
    filename: str = option("tiny_log.json", help="File in the output folder that gets the head pitches")

    def __post_init__(self) -> None:
        check_file_name("filename", self.filename, ".json")


class FrameLogBackend(Backend):
    name = "tiny_log"
    description = "writes the head pitch of every frame to tiny_log.json (plugin test)"
    Options = LogOptions
    options: LogOptions

    def open(self, spec, session):
        super().open(spec, session)
        self.pitches: list[float] = []

    def send(self, frame):
        self.pitches.append(float(np.round(frame.motion.pose[JOINT_INDEX["head"], 0], 6)))

    def close(self):
        write_text_atomic(self.session.out_dir / self.options.filename, json.dumps(self.pitches))

    def outputs(self):
        return [self.session.out_dir / self.options.filename]


class NeedsMissingModule(FrameLogBackend):
    name = "tiny_missing"
    description = "a backend whose dependency is not installed (plugin test)"
    requires = ("convodrive_no_such_module",)
    extra = "imaginary"
