"""Compressed ``.npz`` files written atomically, from arrays in memory or from blocks streamed in.

The same file ``np.savez_compressed`` writes (a zip of ``.npy`` entries, deflated), read by
``np.load``; an entry may be given as ``Blocks`` (its shape, dtype and an iterator of row blocks),
so an array larger than memory never has to be held whole.
"""

from __future__ import annotations

import dataclasses
import os
import zipfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO

import numpy as np

from convodrive.plumbing.atomic import atomic_path


@dataclasses.dataclass(frozen=True)
class Blocks:
    """An array of ``shape`` and ``dtype`` given as consecutive blocks along its first axis."""

    shape: tuple[int, ...]
    dtype: np.dtype
    blocks: Callable[[], Iterator[np.ndarray]]


def write_npz(path: str | os.PathLike[str], entries: Mapping[str, np.ndarray | Blocks]) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as archive:
            for name, value in entries.items():
                with archive.open(f"{name}.npy", "w", force_zip64=True) as fh:
                    if isinstance(value, Blocks):
                        _write_blocks(fh, value)
                    else:
                        np.lib.format.write_array(fh, np.asanyarray(value), allow_pickle=False)
    return path


def _write_blocks(fh: IO[bytes], value: Blocks) -> None:
    dtype = np.dtype(value.dtype)
    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": tuple(value.shape)}
    np.lib.format.write_array_header_1_0(fh, header)
    rows = 0
    for block in value.blocks():
        block = np.ascontiguousarray(block, dtype=dtype)
        if block.shape[1:] != tuple(value.shape[1:]):
            raise ValueError(f"block of shape {block.shape} does not fit an array of shape {value.shape}")
        fh.write(block.tobytes())
        rows += len(block)
    if rows != value.shape[0]:
        raise ValueError(f"blocks gave {rows} rows for an array of shape {value.shape}")
