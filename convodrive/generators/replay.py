"""The ``replay`` generator: plays a recorded motion file in time with the audio.

The audio only sets the length and the clock: one frame per 1/30 s of audio consumed. A clip at
another rate is resampled (slerp for rotations, linear for the rest, nearest for the state); when
the audio outlasts the clip the last frame is held. Voice activity and state come from the clip.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.audio.source import ANALYSIS_RATE, AudioChunk, motion_frames_for
from convodrive.generators.base import Generator
from convodrive.motion import rotations
from convodrive.motion.channels import ConversationState
from convodrive.motion.clip import MotionClip, MotionFrame
from convodrive.plugins.options import PluginOptions, option
from convodrive.plumbing.errors import InputFileError, UserError


def load_motion(path: str | Path) -> MotionClip:
    """A clip from our ``.npz`` or any ``.bvh``; other files are an ``InputFileError``."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        from convodrive.motion.npz import load_clip

        return load_clip(path)
    if suffix == ".bvh":
        from convodrive.motion.bvh import read_bvh

        return read_bvh(path)
    raise InputFileError(path, "not a motion file (replay reads convodrive .npz and .bvh)")


@dataclasses.dataclass(frozen=True)
class ReplayOptions(PluginOptions):
    motion: Path | None = option(None, help="The motion file to play (.npz or .bvh); --motion sets it")


class ReplayGenerator(Generator):
    name = "replay"
    description = "Play a recorded motion file (.npz or .bvh) in time with the audio"
    Options = ReplayOptions
    options: ReplayOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        motion = self.options.motion
        if motion is None:
            raise UserError(
                "generator 'replay' needs a motion file: pass --motion FILE (.npz or .bvh), "
                "or set generator: {replay: {motion: FILE}} in the --config YAML"
            )
        self.clip = load_motion(motion)
        if self.clip.num_frames == 0:
            raise InputFileError(motion, "motion file holds no frames")
        self._quats = rotations.axis_angle_to_quat(self.clip.pose)

    def frame_at(self, index: int) -> MotionFrame:
        """Frame ``index`` of the 30 fps stream: the clip sampled at ``index / 30`` s, held at its end."""
        clip, time = self.clip, index / FPS
        pos = min(time * clip.fps, clip.num_frames - 1)
        i0 = int(np.floor(pos + 1e-9))
        frac = pos - i0
        if frac < 1e-6 or i0 + 1 >= clip.num_frames:
            frame = clip.frame(min(i0, clip.num_frames - 1))
            frame.time = time
            return frame
        i1 = i0 + 1
        q = rotations.quat_slerp(self._quats[i0], self._quats[i1], frac)

        def lerp(a: np.ndarray) -> np.ndarray:
            return ((1 - frac) * a[i0] + frac * a[i1]).astype(np.float32)

        return MotionFrame(
            time=time,
            pose=rotations.quat_to_axis_angle(q).astype(np.float32),
            translation=lerp(clip.translation),
            face=lerp(clip.face),
            vad=lerp(clip.vad),
            state=ConversationState(int(clip.state[i0 if frac < 0.5 else i1])),
        )

    def stream(self, chunks: Iterable[AudioChunk], seed: int = 0) -> Iterator[MotionFrame]:
        emitted = 0
        samples = 0
        for chunk in chunks:
            samples += len(chunk)
            seconds = samples / ANALYSIS_RATE
            due = motion_frames_for(seconds) if chunk.final else int(seconds * FPS + 1e-9)
            while emitted < due:
                yield self.frame_at(emitted)
                emitted += 1
            if chunk.final:
                return
