"""What the learned generators' benchmarks share: model folders of fresh weights (speed does not
depend on the weights) and speech-like dyadic audio."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from convodrive.audio.logmel import MelSpec
from convodrive.audio.source import DyadicAudio
from convodrive.motion import representation as rep


def untrained_folder(model: str, preset: str, int8: bool, root: Path) -> Path:
    """A model folder of ``model``'s fresh weights at ``preset`` with a stand-in data spec (6
    speakers, the default log-mel)."""
    from convodrive.training.export import export_untrained
    from convodrive.training.recipe import DataSpec

    spec = MelSpec()
    dim, bands = rep.FEATURE_DIM, spec.bands
    data = DataSpec(
        info={
            "layout": rep.layout(),
            "corpus": {"name": "none (untrained weights for timing)", "audio_features": spec.to_dict()},
            "speakers": [f"speaker{i}" for i in range(6)],
        },
        arrays={
            "mean": np.zeros(dim, np.float32),
            "std": np.ones(dim, np.float32),
            "count": np.zeros(dim, np.int64),  # no data seen, no channel known constant
            "audio_mean": np.full(bands, -8.0, np.float32),
            "audio_std": np.full(bands, 3.0, np.float32),
        },
    )
    out = root / f"{model}-{preset}-{'int8' if int8 else 'fp32'}"
    export_untrained(model, data, out, preset=preset, int8=int8)
    return out


def speech_like(seconds: float, seed: int = 0) -> DyadicAudio:
    """Two voices taking turns: syllable-rate modulated tones, 1-3 s turns with pauses."""
    rate, rng = 16_000, np.random.default_rng(seed)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    voices = np.zeros((2, n), np.float32)
    pos, who = 0, 0
    while pos < n:
        length = int(rng.uniform(1.0, 3.0) * rate)
        seg = slice(pos, min(n, pos + length))
        env = np.clip(np.sin(2 * np.pi * rng.uniform(3, 5) * t[seg]), 0, None)
        voices[who, seg] = 0.3 * env * np.sin(2 * np.pi * rng.uniform(110, 220) * t[seg])
        pos += length + int(rng.uniform(0.2, 0.6) * rate)
        who = 1 - who
    return DyadicAudio(voices[0], voices[1])
