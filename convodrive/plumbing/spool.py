"""Rows appended to files on disk and read back in blocks: a recording of any length in constant
memory (the recorder keeps two hours of motion on disk, not in RAM, until it writes its files).

A ``RowSpool`` has named fields, each a fixed row shape and dtype, stored raw, one file a field,
in a folder of its own that ``close`` removes. ``spool_folder`` makes that folder beside the
outputs, named after the process, and sweeps the folders of processes that died without closing.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from convodrive.plumbing.atomic import sweep_dead

BLOCK_ROWS = 1024


class RowSpool:
    """Append rows of several named fields; read each back as blocks of ``BLOCK_ROWS`` rows."""

    def __init__(self, folder: Path, fields: dict[str, tuple[tuple[int, ...], np.dtype]]) -> None:
        self.folder = folder
        self.fields = {name: (tuple(shape), np.dtype(dtype)) for name, (shape, dtype) in fields.items()}
        self.rows = 0
        folder.mkdir(parents=True, exist_ok=True)
        self._files: dict[str, IO[bytes]] = {name: open(folder / f"{name}.raw", "wb") for name in self.fields}

    def append(self, row: dict[str, np.ndarray], times: int = 1) -> None:
        """Append one row (a value for every field), ``times`` times over."""
        for name, (shape, dtype) in self.fields.items():
            data = np.asarray(row[name], dtype=dtype)
            if data.shape != shape:
                raise ValueError(f"spool field {name}: row of shape {data.shape}, expected {shape}")
            raw = data.tobytes()
            self._files[name].write(raw * times)
        self.rows += times

    def blocks(self, name: str, block_rows: int = BLOCK_ROWS) -> Iterator[np.ndarray]:
        """The field's rows, in order, as arrays of at most ``block_rows`` rows."""
        shape, dtype = self.fields[name]
        self._files[name].flush()
        per_row = int(np.prod(shape, dtype=np.int64))
        with open(self.folder / f"{name}.raw", "rb") as fh:
            left = self.rows
            while left > 0:
                count = min(block_rows, left)
                data = np.fromfile(fh, dtype=dtype, count=count * per_row)
                if len(data) != count * per_row:
                    raise OSError(f"spool field {name}: file ended early")
                yield data.reshape((count, *shape))
                left -= count

    def close(self) -> None:
        for fh in self._files.values():
            with contextlib.suppress(OSError):
                fh.close()


def spool_folder(parent: Path, name: str) -> Path:
    """A fresh folder ``parent/.{name}.spool-{pid}-XXXX``; folders of dead processes are removed."""
    prefix = f".{name}.spool-"
    sweep_dead(parent, prefix)
    return Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-", dir=parent))
