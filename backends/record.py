"""The ``record`` backend: writes the session's motion and target frames to files.

On ``close`` it writes, each file atomically, into the session's output folder:
``{stem}.npz`` (take 0; further takes as ``{stem}_take{i}.npz``), ``{stem}.bvh`` and
``{stem}_livelink.csv`` (take 0), and, when the target spec has joints, ``targets.npz`` (arrays
``names`` (J,), ``values`` (T, J), ``time`` (T,); named ``{stem}_targets.npz`` for another stem).
Frames that never arrived (dropped in real time) are filled by holding the previous frame, so the
files have one frame per 1/30 s up to the last frame of the run; the report counts them.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.backends.base import Backend, Session
from convodrive.motion.bvh import write_bvh
from convodrive.motion.channels import NUM_BLENDSHAPES
from convodrive.motion.clip import MotionClip
from convodrive.motion.livelink import write_livelink_csv
from convodrive.motion.npz import save_clip
from convodrive.motion.skeleton import NUM_JOINTS
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, check_file_name, option
from convodrive.plumbing.atomic import atomic_path

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class RecordOptions(PluginOptions):
    stem: str = option("motion", help="File name stem of the outputs: STEM.npz, STEM.bvh, STEM_livelink.csv")

    def __post_init__(self) -> None:
        check_file_name("stem", self.stem)


class RecordBackend(Backend):
    name = "record"
    description = "Record the motion (.npz, BVH, Live Link Face CSV) and target frames to files"
    realtime = False
    Options = RecordOptions
    options: RecordOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.stem = self.options.stem
        self._takes: list[dict[str, np.ndarray]] = []
        self._values = np.zeros((0, 0), np.float32)
        self._received = np.zeros(0, bool)
        self._written: list[Path] = []
        self._errors: list[str] = []
        self._filled = 0
        self._num_frames = 0

    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        session.out_dir.mkdir(parents=True, exist_ok=True)

    def send(self, frame: TargetFrame) -> None:
        # Compact float32 rows (under 1 kB a frame and take): a two-hour session is ~200 MB a take.
        if not self._takes:
            self._takes = [_empty_take(0) for _ in frame.takes]
            self._values = np.zeros((0, len(self.spec.names)), np.float32)
        i = frame.index
        if i >= len(self._received):
            self._grow(max(2 * len(self._received), i + 1, 256))
        for k, take in enumerate(self._takes):
            m = frame.takes[min(k, len(frame.takes) - 1)]
            take["pose"][i], take["translation"][i], take["face"][i] = m.pose, m.translation, m.face
            take["vad"][i], take["state"][i] = m.vad, int(m.state)
        if len(self.spec.names):
            self._values[i] = frame.values
        self._received[i] = True

    def _grow(self, capacity: int) -> None:
        def grown(a: np.ndarray) -> np.ndarray:
            out = np.zeros((capacity,) + a.shape[1:], a.dtype)
            out[: len(a)] = a
            return out

        self._takes = [{k: grown(a) for k, a in take.items()} for take in self._takes]
        self._values = grown(self._values)
        self._received = grown(self._received)

    def close(self) -> None:
        """Write every output; a failed file is absent (never partial) and is reported, then raised."""
        if self.session is None:
            return
        clips, values, times = self._assemble()
        out = self.session.out_dir
        jobs: list[tuple[Path, Any]] = []
        for i, clip in enumerate(clips):
            name = f"{self.stem}.npz" if i == 0 else f"{self.stem}_take{i}.npz"
            jobs.append((out / name, lambda p, c=clip: save_clip(c, p)))
        if clips:
            jobs.append((out / f"{self.stem}.bvh", lambda p: write_bvh(clips[0], p)))
            jobs.append((out / f"{self.stem}_livelink.csv", lambda p: write_livelink_csv(clips[0], p)))
        if self.spec.names:
            name = "targets.npz" if self.stem == "motion" else f"{self.stem}_targets.npz"
            jobs.append((out / name, lambda p: self._save_targets(p, values, times)))
        for path, write in jobs:
            try:
                write(path)
                self._written.append(path)
            except Exception as exc:  # one failed file must not stop the others
                log.error("record: cannot write %s: %s", path, exc)
                self._errors.append(f"{path}: {exc.__class__.__name__}: {exc}")
        if self._errors:
            raise OSError(f"record: {len(self._errors)} output(s) failed: {self._errors[0]}")

    def _assemble(self) -> tuple[list[MotionClip], np.ndarray, np.ndarray]:
        """Clips per take and target values, one frame per index, gaps held from the previous frame."""
        assert self.session is not None
        got = np.flatnonzero(self._received)
        if not len(got):
            return [], np.zeros((0, len(self.spec.names))), np.zeros(0)
        # Up to the newest frame received: the scheduler always delivers a run's last frame, and a run
        # stopped early (Ctrl-C) must not be padded out to the audio's length.
        total = int(got[-1]) + 1
        received = np.zeros(total, bool)
        received[: min(total, len(self._received))] = self._received[:total]
        # Each frame's source: the latest received index at or before it (the first one for a gap at the start).
        source = np.maximum.accumulate(np.where(received, np.arange(total), -1))
        source[source < 0] = got[0]
        self._num_frames, self._filled = total, int(total - received.sum())
        fps = self.session.fps
        clips = [
            MotionClip(
                **{k: a[source] for k, a in take.items()}, fps=fps, metadata={"take": k, "seed": self.session.seed}
            )
            for k, take in enumerate(self._takes)
        ]
        return clips, self._values[source], np.arange(total) / fps

    def _save_targets(self, path: Path, values: np.ndarray, times: np.ndarray) -> None:
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(
                    fh,
                    names=np.array(self.spec.names),
                    values=values.astype(np.float32),
                    time=times,
                    units=np.array(self.spec.units),
                    spec=np.array(self.spec.name),
                )

    def health(self) -> dict[str, Any]:
        return {"status": "failed" if self._errors else "ok", "frames_received": int(self._received.sum())}

    def report(self) -> dict[str, Any]:
        return {
            "frames_received": int(self._received.sum()),
            "frames_filled": self._filled,
            "frames_written": self._num_frames,
            "outputs": [str(p) for p in self._written],
            "errors": list(self._errors),
        }

    def outputs(self) -> list[Path]:
        return list(self._written)


def _empty_take(capacity: int) -> dict[str, np.ndarray]:
    return {
        "pose": np.zeros((capacity, NUM_JOINTS, 3), np.float32),
        "translation": np.zeros((capacity, 3), np.float32),
        "face": np.zeros((capacity, NUM_BLENDSHAPES), np.float32),
        "vad": np.zeros((capacity, 2), np.float32),
        "state": np.zeros(capacity, np.int8),
    }
