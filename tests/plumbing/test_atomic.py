"""Atomic writes leave nothing behind, also after a writer was killed with SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from convodrive.plumbing.atomic import atomic_path, write_text_atomic
from convodrive.plumbing.spool import spool_folder

KILLED_WRITER = """
import os, sys, time
from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.spool import spool_folder
spool_folder(__import__('pathlib').Path(sys.argv[1]), "motion")
with atomic_path(sys.argv[1] + "/motion.npz") as tmp:
    tmp.write_bytes(b"x" * 1000)
    print("writing", flush=True)
    time.sleep(60)
"""


def test_a_killed_writers_temporaries_are_swept_by_the_next_write(tmp_path: Path) -> None:
    child = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None and child.stdout.readline().strip() == "writing"
    child.send_signal(signal.SIGKILL)
    child.wait()
    left = sorted(p.name for p in tmp_path.iterdir())
    assert any(n.startswith(".motion.npz.tmp-") for n in left) and any(".spool-" in n for n in left), left

    spool_folder(tmp_path, "motion")  # the next run's spool sweeps the dead one's
    write_text_atomic(tmp_path / "motion.npz", "done")
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != "motion.npz")
    assert len(left) == 1 and f".spool-{os.getpid()}-" in left[0], left
    assert (tmp_path / "motion.npz").read_text() == "done"


def test_a_live_writers_temporaries_are_kept(tmp_path: Path) -> None:
    """Two writers of one destination at once: neither removes the other's file in progress."""
    with atomic_path(tmp_path / "a.npz") as first:
        first.write_text("first")
        write_text_atomic(tmp_path / "a.npz", "second")
        assert first.exists()
    assert (tmp_path / "a.npz").read_text() == "first"
