"""The ``record`` backend: writes the session's motion and target frames to files.

On ``close`` it writes, each file atomically, into the session's output folder:
``{stem}.npz`` (take 0; further takes as ``{stem}_take{i}.npz``), ``{stem}.bvh`` and
``{stem}_livelink.csv`` (take 0), and, when the target spec has joints, ``targets.npz`` (arrays
``names`` (J,), ``values`` (T, J), ``time`` (T,); named ``{stem}_targets.npz`` for another stem).
Frames that never arrived (dropped in real time) are filled by holding the previous frame, so the
files have one frame per 1/30 s up to the last frame of the run; the report counts them.

Frames go to disk as they arrive (a spool folder beside the outputs, removed at close), and the
files are written from it block by block, so a run of any length records in constant memory.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.backends.base import Backend, Session
from convodrive.motion.bvh import write_bvh_blocks
from convodrive.motion.clip import MotionFrame
from convodrive.motion.livelink import write_livelink_blocks
from convodrive.motion.npz import CLIP_FIELDS, write_clip_arrays
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, check_file_name, option
from convodrive.plumbing.npzfile import Blocks, write_npz
from convodrive.plumbing.spool import RowSpool, spool_folder

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
    light = True  # a frame is a few rows appended to spool files
    Options = RecordOptions
    options: RecordOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.stem = self.options.stem
        self._folder: Path | None = None
        self._takes: list[RowSpool] = []
        self._values: RowSpool | None = None
        self._last: tuple[list[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None
        self._next = 0  # the index the next frame written will have
        self._received = 0
        self._filled = 0
        self._out_of_order = 0
        self._written: list[Path] = []
        self._errors: list[str] = []

    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        session.out_dir.mkdir(parents=True, exist_ok=True)
        self._folder = spool_folder(session.out_dir, self.stem)

    def send(self, frame: TargetFrame) -> None:
        if self._folder is None:
            raise RuntimeError("record: send() before open()")
        if not self._takes:
            self._takes = [RowSpool(self._folder / f"take{k}", CLIP_FIELDS) for k in range(len(frame.takes))]
            if self.spec.names:
                joints = len(self.spec.names)
                self._values = RowSpool(self._folder / "targets", {"values": ((joints,), np.dtype(np.float32))})
        if frame.index < self._next:  # already written (or filled): never rewrite the past
            self._out_of_order += 1
            return
        rows = [_row(frame.takes[min(k, len(frame.takes) - 1)]) for k in range(len(self._takes))]
        values = {"values": np.asarray(frame.values, np.float32)} if self._values is not None else {}
        gap = frame.index - self._next
        if gap:  # dropped frames hold the previous one (the first frame, for a gap at the start)
            held_rows, held_values = self._last if self._last is not None else (rows, values)
            self._append(held_rows, held_values, gap)
            self._filled += gap
        self._append(rows, values, 1)
        self._last = (rows, values)
        self._received += 1

    def _append(self, rows: list[dict[str, np.ndarray]], values: dict[str, np.ndarray], times: int) -> None:
        for spool, row in zip(self._takes, rows):
            spool.append(row, times)
        if self._values is not None:
            self._values.append(values, times)
        self._next += times

    def close(self) -> None:
        """Write every output; a failed file is absent (never partial) and is reported, then raised."""
        if self.session is None or self._folder is None:
            return
        try:
            self._write_outputs()
        finally:
            for spool in [*self._takes, *([self._values] if self._values else [])]:
                spool.close()
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None
        if self._errors:
            raise OSError(f"record: {len(self._errors)} output(s) failed: {self._errors[0]}")

    def _write_outputs(self) -> None:
        assert self.session is not None
        out, fps, total = self.session.out_dir, self.session.fps, self._next
        jobs: list[tuple[Path, Any]] = []
        for k, spool in enumerate(self._takes):
            name = f"{self.stem}.npz" if k == 0 else f"{self.stem}_take{k}.npz"
            arrays = {field: _blocks(spool, field) for field in CLIP_FIELDS}
            metadata = {"take": k, "seed": self.session.seed}
            jobs.append((out / name, lambda p, a=arrays, m=metadata: write_clip_arrays(p, a, fps, m)))
        if self._takes and total:
            take = self._takes[0]
            jobs.append(
                (
                    out / f"{self.stem}.bvh",
                    lambda p: write_bvh_blocks(p, total, fps, _pairs(take, "pose", "translation")),
                )
            )
            jobs.append(
                (
                    out / f"{self.stem}_livelink.csv",
                    lambda p: write_livelink_blocks(p, fps, _pairs(take, "face", "pose")),
                )
            )
        if self.spec.names and self._values is not None:
            name = "targets.npz" if self.stem == "motion" else f"{self.stem}_targets.npz"
            jobs.append((out / name, self._save_targets))
        for path, write in jobs:
            try:
                write(path)
                self._written.append(path)
            except Exception as exc:  # one failed file must not stop the others
                log.error("record: cannot write %s: %s", path, exc)
                self._errors.append(f"{path}: {exc.__class__.__name__}: {exc}")

    def _save_targets(self, path: Path) -> None:
        assert self._values is not None and self.session is not None
        write_npz(
            path,
            {
                "names": np.array(self.spec.names),
                "values": _blocks(self._values, "values"),
                "time": Blocks((self._next,), np.dtype(np.float64), lambda: _times(self._next, self.session.fps)),
                "units": np.array(self.spec.units),
                "spec": np.array(self.spec.name),
            },
        )

    def health(self) -> dict[str, Any]:
        out: dict[str, Any] = {"status": "failed" if self._errors else "ok", "frames_received": self._received}
        if self._errors:
            out["reason"] = "; ".join(self._errors)
        return out

    def report(self) -> dict[str, Any]:
        return {
            "frames_received": self._received,
            "frames_filled": self._filled,
            "frames_written": self._next,
            "frames_out_of_order": self._out_of_order,
            "outputs": [str(p) for p in self._written],
            "errors": list(self._errors),
        }

    def outputs(self) -> list[Path]:
        return list(self._written)


def _row(motion: MotionFrame) -> dict[str, np.ndarray]:
    return {
        "pose": motion.pose,
        "translation": motion.translation,
        "face": motion.face,
        "vad": motion.vad,
        "state": np.int8(int(motion.state)),
    }


def _blocks(spool: RowSpool, field: str) -> Blocks:
    shape, dtype = spool.fields[field]
    return Blocks((spool.rows, *shape), dtype, lambda: spool.blocks(field))


def _pairs(spool: RowSpool, a: str, b: str) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    return zip(spool.blocks(a), spool.blocks(b))


def _times(count: int, fps: float, block: int = 4096) -> Iterator[np.ndarray]:
    for start in range(0, count, block):
        yield np.arange(start, min(start + block, count)) / fps
