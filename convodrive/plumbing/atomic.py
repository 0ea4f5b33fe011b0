"""Atomic file output: every file convodrive writes is complete or absent, never half-written.

Writers produce a temporary file in the destination's folder and rename it over the destination
only when they finish, so an error or Ctrl-C leaves the previous file (or nothing) in place.
A temporary name carries its process id, so a write cut short by SIGKILL (which runs no cleanup)
is swept away by the next write to the same destination (``sweep_dead``).
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()
"""Read once at import: os.umask is process-wide, so reading it while threads write is racy."""


@contextlib.contextmanager
def atomic_path(destination: str | os.PathLike[str], suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``destination``; rename it into place on success.

    ``suffix`` defaults to the destination's own, because some writers (numpy, ffmpeg) pick the
    format from the file extension.
    """
    dest = Path(destination)
    dest.parent.mkdir(parents=True, exist_ok=True)
    prefix = f".{dest.name}.tmp-"
    sweep_dead(dest.parent, prefix)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f"{prefix}{os.getpid()}-", suffix=suffix if suffix is not None else dest.suffix, dir=dest.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; outputs get the usual mode
        os.replace(tmp, dest)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_folder(destination: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield an empty folder beside ``destination``; on success it replaces ``destination`` (a
    model folder: complete or absent, the old one kept until the new one is whole)."""
    dest = Path(destination)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    try:
        yield tmp
        tmp.chmod(0o755)
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def write_text_atomic(destination: str | os.PathLike[str], text: str) -> None:
    with atomic_path(destination) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_bytes_atomic(destination: str | os.PathLike[str], data: bytes) -> None:
    with atomic_path(destination) as tmp:
        tmp.write_bytes(data)


def sweep_dead(parent: Path, prefix: str) -> None:
    """Remove the files and folders ``parent/{prefix}{pid}-…`` whose process no longer runs."""
    for stale in parent.glob(f"{glob.escape(prefix)}*"):
        pid = stale.name[len(prefix) :].split("-", 1)[0]
        if not pid.isdigit() or process_alive(int(pid)):
            continue
        if stale.is_dir() and not stale.is_symlink():
            shutil.rmtree(stale, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                stale.unlink()


def process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
