"""A plugin that lives outside convodrive: it nods at 1 Hz and logs the frames it receives."""

from __future__ import annotations

import json
import math

import numpy as np

from convodrive.audio.source import ANALYSIS_RATE, motion_frames_for
from convodrive.backends.base import Backend
from convodrive.generators.base import Generator
from convodrive.motion.clip import MotionFrame
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.plumbing.atomic import write_text_atomic


class NodGenerator(Generator):
    name = "tiny_nod"
    description = "nods the head once a second, whatever is said (plugin test)"

    def stream(self, chunks, seed=0):
        samples = 0
        emitted = 0
        for chunk in chunks:
            samples += len(chunk)
            due = motion_frames_for(samples / ANALYSIS_RATE) if chunk.final else int(samples / ANALYSIS_RATE * 30)
            while emitted < due:
                frame = MotionFrame.neutral(emitted / 30)
                frame.pose[JOINT_INDEX["head"], 0] = 0.2 * math.sin(2 * math.pi * emitted / 30)
                yield frame
                emitted += 1


class FrameLogBackend(Backend):
    name = "tiny_log"
    description = "writes the head pitch of every frame to tiny_log.json (plugin test)"

    def open(self, spec, session):
        super().open(spec, session)
        self.pitches: list[float] = []

    def send(self, frame):
        self.pitches.append(float(np.round(frame.motion.pose[JOINT_INDEX["head"], 0], 6)))

    def close(self):
        write_text_atomic(self.session.out_dir / "tiny_log.json", json.dumps(self.pitches))

    def outputs(self):
        return [self.session.out_dir / "tiny_log.json"]


class NeedsMissingModule(FrameLogBackend):
    name = "tiny_missing"
    description = "a backend whose dependency is not installed (plugin test)"
    requires = ("convodrive_no_such_module",)
    extra = "imaginary"
