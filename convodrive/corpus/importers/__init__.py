"""Importers: corpora users bring, written into the one corpus format.

Each importer module has ``LICENCE`` (the source's terms, which trained models inherit),
``find(src, options)`` (every item of the source, checked
for the files it needs before anything is written) and ``load(item, options)`` (the item's
recordings). ``import_corpus`` runs one into a ``CorpusWriter``; a bad file anywhere is one line
naming it, and the half-made corpus is removed.
"""

from __future__ import annotations

import dataclasses
import importlib
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from convodrive.corpus.importers.options import ImportOptions
from convodrive.corpus.writer import CorpusWriter
from convodrive.plumbing.errors import InputFileError, UserError

KINDS: dict[str, tuple[str, str]] = {
    "beat2": ("convodrive.corpus.importers.beat2", "smplxflame_30/*.npz (SMPL-X) with wave16k/*.wav"),
    "show": ("convodrive.corpus.importers.show", "<speaker>/<video>/<clip>/<clip>.pkl (SMPL-X fits) with .wav"),
    "seamless": (
        "convodrive.corpus.importers.seamless",
        "<interaction>_<participant>.wav and .npz (SMPL-H), paired into dyads",
    ),
    "own": ("convodrive.corpus.importers.own", "WAV files, each with a .npz, .bvh and/or Live Link .csv of its name"),
}
"""Kind -> (module, what its source folder holds)."""


def importer(kind: str) -> ModuleType:
    if kind not in KINDS:
        raise UserError(f"unknown corpus kind {kind!r} (choose {', '.join(KINDS)})")
    return importlib.import_module(KINDS[kind][0])


@dataclasses.dataclass(frozen=True)
class ImportReport:
    folder: Path
    kind: str
    conversations: int
    hours: float
    seconds: float

    def to_json(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "folder": str(self.folder), "hours": round(self.hours, 4)}


def import_corpus(
    kind: str,
    src: str | Path,
    out: str | Path,
    seed: int = 0,
    options: ImportOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ImportReport:
    """Import the ``kind`` corpus in ``src`` into the new corpus folder ``out``."""
    module = importer(kind)
    options = options or ImportOptions()
    src = Path(src)
    if not src.is_dir():
        raise InputFileError(src, "no such folder" if not src.exists() else "not a folder")
    start = time.perf_counter()
    items = module.find(src, options)
    source = {
        "kind": kind,
        "from": str(src.resolve()),
        "speaker": options.speaker,
        "mano": None if options.mano is None else str(options.mano),
    }
    frames = conversations = 0
    ids: set[str] = set()
    licence = str(module.LICENCE)
    with CorpusWriter(out, source, seed=seed, licence=licence) as writer:
        for i, item in enumerate(items, 1):
            for rec in module.load(item, options):
                base, n = rec.id, 1
                while rec.id in ids:  # the same clip name in two folders
                    n += 1
                    rec.id = f"{base[:120]}-{n}"
                ids.add(rec.id)
                writer.add(rec)
                frames += rec.takes[0].num_frames
                conversations += 1
            if progress:
                progress(i, len(items))
    return ImportReport(Path(out), kind, conversations, frames / 30 / 3600, time.perf_counter() - start)
