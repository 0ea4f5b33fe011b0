"""A run's ``--out`` folder: checked before anything runs, and left clean by a run that fails.

A run that fails before its first checkpoint leaves nothing behind (its ``run.json``,
``metrics.csv`` and TensorBoard files describe no weights); a run that fails later keeps its
checkpoints and logs, from which it resumes.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from convodrive.plumbing.errors import UserError
from convodrive.training.checkpoint import list_checkpoints, remove_stale_temps

RUN_FILES = ("run.json", "metrics.csv", "tensorboard", "checkpoints")
"""What a run writes in its folder."""


def check_out(out: Path) -> None:
    """``--out`` must be a folder this process can write, or a new one it can create."""
    if out.exists():
        if not out.is_dir():
            raise UserError(f"--out {out}: exists and is not a folder; choose a new or run folder")
        if not os.access(out, os.W_OK | os.X_OK):
            raise UserError(f"--out {out}: cannot write in this folder (permission denied)")
        return
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise UserError(f"--out {out}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"--out {out}: cannot create it in {parent} (permission denied)")


@contextlib.contextmanager
def cleaned_if_failed(out: Path, enabled: bool) -> Iterator[None]:
    """Remove the temporary folders of killed checkpoint saves now, and, if what runs inside fails
    (or is interrupted) while ``out`` holds no checkpoint, every file of the run (module doc)."""
    created = not out.exists()
    if enabled:
        remove_stale_temps(out / "checkpoints")
    try:
        yield
    except BaseException:
        if enabled and not list_checkpoints(out / "checkpoints"):
            if created:
                shutil.rmtree(out, ignore_errors=True)
            else:
                for name in RUN_FILES:
                    path = out / name
                    if path.is_dir():
                        shutil.rmtree(path, ignore_errors=True)
                    elif path.exists():
                        path.unlink()
        raise
