"""Fixtures of the backends' tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.audio.synth import speak


@pytest.fixture
def talk(tmp_path: Path) -> Path:
    """Two seconds of self speaking (channel 0), the partner silent: a mouth that moves."""
    voice = speak("Hello there, how are you today?", rate=170)[: 2 * 16000]
    stereo = np.zeros((len(voice) + 8000, 2), np.float32)
    stereo[4000 : 4000 + len(voice), 0] = voice
    path = tmp_path / "talk.wav"
    sf.write(path, stereo, 16000)
    return path
