"""Shard files: uncompressed ``.npz`` archives whose arrays are read in place through memory maps.

An uncompressed ``.npz`` is a zip of ``.npy`` files stored as they are, so each array sits at a
fixed offset of the shard: ``ShardMap`` finds that offset and maps the array, and reading a
180-frame window of an hour-long conversation touches only that window's pages. ``np.load`` reads
the same files, so any tool can open a shard without convodrive.
"""

from __future__ import annotations

import os
import struct
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.errors import InputFileError

_LOCAL_HEADER = struct.Struct("<4sHHHHHIIIHH")
_LOCAL_MAGIC = b"PK\x03\x04"
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def write_shard(path: str | os.PathLike[str], arrays: dict[str, np.ndarray]) -> int:
    """Write ``arrays`` as an uncompressed ``.npz`` atomically; return its size in bytes."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            savez: Any = np.savez  # its stubs type **arrays against allow_pickle
            savez(fh, allow_pickle=False, **arrays)
        size = tmp.stat().st_size
    return size


class ShardMap:
    """The arrays of one shard, memory-mapped. Every problem is one ``InputFileError`` line."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputFileError(
                self.path, "shard missing: the corpus manifest lists it but the folder does not hold it"
            )
        size = self.path.stat().st_size
        self._arrays: dict[str, np.ndarray] = {}
        try:
            with zipfile.ZipFile(self.path) as zf, open(self.path, "rb") as fh:
                for info in zf.infolist():
                    if not info.filename.endswith(".npy"):
                        continue
                    if info.compress_type != zipfile.ZIP_STORED:
                        raise InputFileError(self.path, f"array {info.filename} is compressed; shards are stored")
                    fh.seek(info.header_offset)
                    fields = _LOCAL_HEADER.unpack(fh.read(_LOCAL_HEADER.size))
                    if fields[0] != _LOCAL_MAGIC:
                        raise InputFileError(self.path, f"corrupt zip entry {info.filename}")
                    fh.seek(info.header_offset + _LOCAL_HEADER.size + fields[9] + fields[10])
                    data_start = fh.tell()
                    version = np.lib.format.read_magic(fh)
                    if version not in _HEADER_READERS:
                        raise InputFileError(self.path, f"array {info.filename} uses .npy version {version}")
                    shape, fortran, dtype = _HEADER_READERS[version](fh)
                    offset = fh.tell()
                    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
                    if dtype.hasobject:
                        raise InputFileError(self.path, f"array {info.filename} holds Python objects")
                    if offset + nbytes > size or offset - data_start + nbytes != info.file_size:
                        raise InputFileError(self.path, f"truncated: array {info.filename} runs past the end")
                    key = info.filename[: -len(".npy")]
                    if nbytes == 0:
                        self._arrays[key] = np.zeros(shape, dtype)
                    else:
                        self._arrays[key] = np.memmap(
                            self.path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C"
                        )
        except (zipfile.BadZipFile, EOFError, struct.error, ValueError, OSError) as exc:
            detail = str(exc).split("\n")[0] or exc.__class__.__name__
            raise InputFileError(self.path, f"truncated or corrupt shard ({detail})") from None

    def __contains__(self, key: str) -> bool:
        return key in self._arrays

    def keys(self) -> list[str]:
        return list(self._arrays)

    def array(self, key: str) -> np.ndarray:
        try:
            return self._arrays[key]
        except KeyError:
            raise InputFileError(self.path, f"has no array {key!r} (the manifest expects it)") from None
