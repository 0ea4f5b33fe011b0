"""Shared fixtures: the CLI as a user runs it, and short synthetic conversations."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

REPO = Path(__file__).resolve().parents[1]


def run_cli(
    *args: str, env: dict[str, str] | None = None, timeout: float = 300, cwd: Path | None = None
) -> subprocess.CompletedProcess:
    """Run ``convodrive`` in a fresh interpreter, as a user's shell would."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "convodrive.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=full_env,
        cwd=cwd,
    )


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
