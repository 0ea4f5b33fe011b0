"""A run's output folder: checked and made before anything runs, removed again if the run fails
and leaves it empty.

A folder that cannot take the outputs (it is a file, lies under a file, or cannot be written) is a
``UserError`` before the run starts, never a traceback after it: the writability check writes and
removes a probe file, which also catches read-only file systems.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from convodrive.plumbing.errors import UserError


class OutputFolder:
    """The folder ``path``, named ``label`` in messages (e.g. ``--out out/``)."""

    def __init__(self, path: str | os.PathLike[str], label: str | None = None) -> None:
        self.path = Path(path)
        self.label = label or f"--out {self.path}"
        self.created: list[Path] = []
        """Folders this object made, deepest last: the ones ``discard_if_empty`` may remove."""

    def prepare(self) -> Path:
        """Check that the folder can take files, making it (and missing parents) if needed."""
        existing = self.path
        missing: list[Path] = []
        while not existing.exists():
            if existing.is_symlink():
                raise UserError(f"{self.label}: {existing} is a broken link")
            missing.append(existing)
            if existing.parent == existing:
                break
            existing = existing.parent
        if existing.exists() and not existing.is_dir():
            where = "is a file, not a folder" if existing == self.path else f"{existing} is a file, not a folder"
            raise UserError(f"{self.label}: {where}")
        for folder in reversed(missing):
            try:
                folder.mkdir()
            except FileExistsError:
                pass
            except OSError as exc:
                self.discard_if_empty()
                raise UserError(f"{self.label}: cannot create {folder} ({_reason(exc)})") from None
            self.created.append(folder)
        self._check_writable()
        return self.path

    def _check_writable(self) -> None:
        try:
            fd, probe = tempfile.mkstemp(prefix=".convodrive-probe-", dir=self.path)
        except OSError as exc:
            self.discard_if_empty()
            raise UserError(f"{self.label}: cannot write there ({_reason(exc)})") from None
        os.close(fd)
        os.unlink(probe)

    def discard_if_empty(self) -> None:
        """Remove the folders ``prepare`` made, deepest first, as long as they are empty."""
        for folder in reversed(self.created):
            try:
                folder.rmdir()
            except OSError:  # not empty (or gone): keep it and everything above it
                break
        self.created = [f for f in self.created if f.exists()]

    @contextlib.contextmanager
    def kept_on_success(self) -> Iterator[Path]:
        """``prepare``, then ``discard_if_empty`` when the block raises."""
        self.prepare()
        try:
            yield self.path
        except BaseException:
            self.discard_if_empty()
            raise


def _reason(exc: OSError) -> str:
    return (exc.strerror or exc.__class__.__name__).lower()
