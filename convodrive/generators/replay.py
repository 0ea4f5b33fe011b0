"""The ``replay`` generator: plays recorded motion files in time with the audio.

The audio only sets the length and the clock: one frame per 1/30 s of audio consumed. Files are
read by the one motion loader (``.npz``, BVH, Live Link CSV) and sampled at 30 fps by the one
resampler (``convodrive.motion.resample``), so a clip animates the same here and in
``convodrive render``, which is this generator feeding the render backend. With several files,
take k plays file k, so K clips come out side by side as K takes do.

A clip and the audio rarely last exactly as long: a longer clip is cut where the audio ends, a
shorter one holds its last frame. Both are logged as warnings and listed in the run report, as
is a part of the motion the file does not carry (a BVH has no face; a Live Link take no body).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from convodrive import FPS
from convodrive.audio.source import ANALYSIS_RATE, AudioChunk, motion_frames_for
from convodrive.generators.base import Generator
from convodrive.motion.clip import MotionClip, MotionFrame
from convodrive.motion.load import FORMATS, absent_parts, load_motion
from convodrive.motion.resample import ClipSampler
from convodrive.plugins.options import PluginOptions, option
from convodrive.plumbing.errors import UserError

log = logging.getLogger(__name__)

MAX_FILES = 16
"""As many files as a run has takes at most (``--samples`` 1 to 16)."""


@dataclasses.dataclass(frozen=True)
class ReplayOptions(PluginOptions):
    motion: Path | list[Path] | None = option(
        None,
        help=f"Motion file to play ({FORMATS}), or a list: take k plays file k.",
        max_items=MAX_FILES,
    )


class ReplayGenerator(Generator):
    name = "replay"
    description = "Play recorded motion (.npz, BVH, Live Link CSV) in time with the audio"
    Options = ReplayOptions
    options: ReplayOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        motion = self.options.motion
        paths = motion if isinstance(motion, list) else [motion] if motion else []
        if not paths:
            raise UserError(
                "generator 'replay' needs a motion file: pass --motion FILE (.npz, .bvh or .csv), "
                "or set generator: {replay: {motion: FILE}} in the --config YAML"
            )
        self.paths = [Path(p) for p in paths]
        self.samplers = [ClipSampler(load_motion(p), FPS) for p in self.paths]
        self.warnings: list[str] = []
        for path, sampler in zip(self.paths, self.samplers):
            for part in absent_parts(sampler.clip):
                self._warn(f"{path}: plays no {part}")

    @property
    def clip(self) -> MotionClip:
        """The first file's clip (a single-file replay's only one)."""
        return self.samplers[0].clip

    def frame_at(self, index: int) -> MotionFrame:
        """Frame ``index`` of the 30 fps stream of the first file."""
        return self.samplers[0].frame(index)

    def stream(self, chunks: Iterable[AudioChunk], seed: int = 0) -> Iterator[MotionFrame]:
        for takes in self._play(chunks, [0]):
            yield takes[0]

    def stream_takes(self, chunks: Iterable[AudioChunk], seeds: Sequence[int]) -> Iterator[tuple[MotionFrame, ...]]:
        """Take k plays file k (files repeat when there are more takes than files); seeds do not matter."""
        return self._play(chunks, [k % len(self.samplers) for k in range(len(seeds))])

    def report(self) -> dict[str, Any]:
        return {
            "motion": [
                {"path": str(p), "fps": s.clip.fps, "frames": s.clip.num_frames, "seconds": round(s.clip.duration, 3)}
                for p, s in zip(self.paths, self.samplers)
            ],
            "warnings": list(self.warnings),
        }

    def _play(self, chunks: Iterable[AudioChunk], files: list[int]) -> Iterator[tuple[MotionFrame, ...]]:
        emitted = 0
        samples = 0
        for chunk in chunks:
            samples += len(chunk)
            seconds = samples / ANALYSIS_RATE
            due = motion_frames_for(seconds) if chunk.final else int(seconds * FPS + 1e-9)
            while emitted < due:
                yield tuple(self.samplers[f].frame(emitted) for f in files)
                emitted += 1
            if chunk.final:
                self._check_length(emitted, sorted(set(files)))
                return

    def _check_length(self, frames: int, files: list[int]) -> None:
        """Warn, once the audio's length is known, about clips cut short or held at their end."""
        audio_s = frames / FPS
        for f in files:
            path, sampler = self.paths[f], self.samplers[f]
            clip_s = sampler.num_frames / FPS
            if sampler.num_frames > frames:
                self._warn(
                    f"{path}: the clip lasts {clip_s:.2f} s but the audio {audio_s:.2f} s: "
                    f"its last {clip_s - audio_s:.2f} s are not played"
                )
            elif sampler.num_frames < frames:
                self._warn(
                    f"{path}: the clip lasts {clip_s:.2f} s but the audio {audio_s:.2f} s: "
                    f"its last frame is held for {audio_s - clip_s:.2f} s"
                )

    def _warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)
            log.warning("replay: %s", message)
