"""Keep freed memory in the process's heap (glibc), for training's same-sized buffers step after step.

glibc serves a large block with a fresh mapping, and gives the heap's free top back to the kernel
once it passes a threshold. A training step frees hundreds of megabytes of activations and
allocates them again in the next, so every step faulted its pages in anew: a2p's face stage on one
core took 1.8 million page faults and 9 to 12 s of system time in 40 steps. With both thresholds
raised the freed blocks serve the next step: 0.3 million faults, about 8 % less CPU time.
Allocation only: nothing computed changes.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20
"""Blocks below this come from the heap: glibc's largest allowed value on 64-bit."""
TRIM_THRESHOLD = 1 << 30
"""Free memory the heap keeps at its top before it returns any to the kernel."""


def keep_freed_blocks() -> bool:
    """Raise glibc's mmap and trim thresholds for this process; False where the C library has no
    ``mallopt`` or refuses (macOS, musl), which leaves the allocator as it was."""
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
