"""keep_freed_blocks: freed large blocks serve the next allocations without new page faults."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from convodrive.training.heap import keep_freed_blocks

# Ten rounds of what a training step does to the heap: 30 blocks of 5 MB live at once, then freed.
_PROBE = """
import resource, sys
import numpy as np
from convodrive.training.heap import keep_freed_blocks
if sys.argv[1] == "keep":
    assert keep_freed_blocks()
def step():
    blocks = [np.ones(1_250_000, np.float32) for _ in range(30)]
    del blocks
step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    step()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _page_faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1])


GLIBC = platform.libc_ver()[0] == "glibc"


@pytest.mark.skipif(not GLIBC, reason="mallopt's thresholds are glibc's")
def test_freed_blocks_serve_the_next_step_without_page_faults() -> None:
    default, kept = _page_faults("default"), _page_faults("keep")
    assert default > 50_000, default  # 10 x 150 MB faulted in again: what the setting is for
    assert kept < default / 20, (kept, default)


def test_the_setting_reports_whether_the_allocator_took_it() -> None:
    assert keep_freed_blocks() is GLIBC
