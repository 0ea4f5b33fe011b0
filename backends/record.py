"""The ``record`` backend: writes the session's motion and target frames to files.

On ``close`` it writes, each file atomically, into the session's output folder:
``{stem}.npz`` (take 0; further takes as ``{stem}_take{i}.npz``), ``{stem}.bvh`` and
``{stem}_livelink.csv`` (take 0), and, when the target spec has joints, ``targets.npz`` (arrays
``names`` (J,), ``values`` (T, J), ``time`` (T,); named ``{stem}_targets.npz`` for another stem).
Frames that never arrived (dropped in real time) are filled by holding the previous frame, so the
files always have one frame per 1/30 s; the report counts them.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.atomic import atomic_path
from convodrive.backends.base import Backend, Session
from convodrive.errors import UserError
from convodrive.motion.bvh import write_bvh
from convodrive.motion.clip import MotionClip
from convodrive.motion.livelink import write_livelink_csv
from convodrive.motion.npz import save_clip
from convodrive.targets import TargetFrame, TargetSpec

log = logging.getLogger(__name__)


class RecordBackend(Backend):
    name = "record"
    description = "Record the motion (.npz, BVH, Live Link Face CSV) and target frames to files"
    realtime = False

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        super().__init__(options)
        stem = str(self.options.get("stem", "motion"))
        if not stem or "/" in stem or "\\" in stem or stem.startswith("."):
            raise UserError(f"backend 'record': option stem must be a plain file name, got {stem!r}")
        self.stem = stem
        self._frames: dict[int, TargetFrame] = {}
        self._written: list[Path] = []
        self._errors: list[str] = []
        self._filled = 0
        self._num_frames = 0

    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        session.out_dir.mkdir(parents=True, exist_ok=True)

    def send(self, frame: TargetFrame) -> None:
        # Frames are small (a few kB); a two-hour session holds about 200 MB per take.
        self._frames[frame.index] = frame

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
        received = sorted(self._frames)
        if not received:
            return [], np.zeros((0, len(self.spec.names))), np.zeros(0)
        total = max(received[-1] + 1, self.session.num_frames or 0)
        self._num_frames = total
        ordered: list[TargetFrame] = []
        current = self._frames[received[0]]  # a gap at the start takes the first frame that came
        for i in range(total):
            if i in self._frames:
                current = self._frames[i]
            else:
                self._filled += 1
            ordered.append(current)
        fps = self.session.fps
        num_takes = max(len(f.takes) for f in ordered)
        clips = []
        for k in range(num_takes):
            frames = [f.takes[min(k, len(f.takes) - 1)] for f in ordered]
            clips.append(MotionClip.from_frames(frames, fps=fps, metadata={"take": k, "seed": self.session.seed}))
        values = np.stack([np.asarray(f.values, np.float64) for f in ordered]) if self.spec.names else np.zeros((total, 0))
        return clips, values, np.arange(total) / fps

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
        return {"status": "failed" if self._errors else "ok", "frames_received": len(self._frames)}

    def report(self) -> dict[str, Any]:
        return {
            "frames_received": len(self._frames),
            "frames_filled": self._filled,
            "frames_written": self._num_frames,
            "outputs": [str(p) for p in self._written],
            "errors": list(self._errors),
        }

    def outputs(self) -> list[Path]:
        return list(self._written)

