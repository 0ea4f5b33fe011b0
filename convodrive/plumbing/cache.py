"""Derived files made once per machine and kept: the per-user cache folder.

``cached_folder(name, key, make)`` returns ``CACHE/name-key``, calling ``make(folder)`` to fill it
the first time. The folder is filled under a temporary name and renamed into place, so a run
killed part-way (even with SIGKILL) leaves no half-made entry, only a ``.partial-*`` folder that
the next call sweeps away; two runs racing keep one result. The cache is
``$CONVODRIVE_CACHE_DIR``, else ``$XDG_CACHE_HOME/convodrive``, else ``~/.cache/convodrive``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterable
from pathlib import Path

_STALE_SECONDS = 3600.0
"""A ``.partial-*`` folder older than this belongs to a run that died while filling it."""


def cache_root() -> Path:
    explicit = os.environ.get("CONVODRIVE_CACHE_DIR")
    if explicit:
        return Path(explicit)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "convodrive"


def cache_key(parts: Iterable[object]) -> str:
    """A short hash of whatever the cached content depends on."""
    digest = hashlib.sha256()
    for part in parts:
        digest.update(repr(part).encode())
        digest.update(b"\0")
    return digest.hexdigest()[:16]


def cached_folder(name: str, key: str, make: Callable[[Path], None]) -> Path:
    """``CACHE/name-key``, made by ``make`` on first use. ``OSError`` when the cache cannot be written."""
    root = cache_root()
    final = root / f"{name}-{key}"
    if final.is_dir():
        return final
    root.mkdir(parents=True, exist_ok=True)
    _sweep_partial(root, name)
    partial = Path(tempfile.mkdtemp(prefix=f".partial-{name}-", dir=root))
    try:
        make(partial)
        try:
            os.rename(partial, final)
        except OSError:
            if not final.is_dir():  # not another run that got there first
                raise
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return final


def _sweep_partial(root: Path, name: str) -> None:
    now = time.time()
    for folder in root.glob(f".partial-{name}-*"):
        try:
            if now - folder.stat().st_mtime > _STALE_SECONDS:
                shutil.rmtree(folder, ignore_errors=True)
        except OSError:
            continue
