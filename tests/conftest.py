"""Shared fixtures: the CLI as a user runs it, and short synthetic conversations."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

REPO = Path(__file__).resolve().parents[1]


def run_cli(
    *args: str,
    env: dict[str, str] | None = None,
    timeout: float = 300,
    cwd: Path | None = None,
    as_user: bool = False,
) -> subprocess.CompletedProcess:
    """Run ``convodrive`` in a fresh interpreter, as a user's shell would. ``as_user``: without
    root's power to read any file, so a file that is not readable reads as a user meets it."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "convodrive.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=full_env,
        cwd=cwd,
        preexec_fn=_drop_read_override if as_user else None,
    )


def _drop_read_override() -> None:
    """Drop CAP_DAC_OVERRIDE and CAP_DAC_READ_SEARCH from the bounding set before exec (Linux), so
    that even root is refused a file with mode 000."""
    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for capability in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        if libc.prctl(24, capability, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


@pytest.fixture
def tone_dialogue(tmp_path: Path) -> Path:
    """A 3 s stereo WAV at 44.1 kHz: self voiced in the first half, the partner in the second."""
    sr = 44_100
    t = np.arange(int(3.0 * sr)) / sr
    voice = 0.3 * np.sin(2 * np.pi * 180 * t) * (0.6 + 0.4 * np.sin(2 * np.pi * 4 * t))
    left = np.where(t < 1.5, voice, 0.0)
    right = np.where(t >= 1.5, voice, 0.0)
    path = tmp_path / "tones.wav"
    sf.write(path, np.stack([left, right], axis=1).astype(np.float32), sr, subtype="PCM_16")
    return path
