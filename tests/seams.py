"""Frame changes at a streamed clip's window seams, against those inside its windows."""

from __future__ import annotations

import numpy as np


def seam_changes(pose: np.ndarray, hop: int) -> tuple[np.ndarray, np.ndarray]:
    """(at each seam, inside windows): the largest joint-angle change of each frame against the
    one before, in radians, split by whether the frame is a window's first new one."""
    change = np.abs(np.diff(pose, axis=0)).max(axis=(1, 2))  # change[i]: frame i+1 against frame i
    seams = np.arange(hop, len(change) + 1, hop) - 1
    return change[seams], np.delete(change, seams)
