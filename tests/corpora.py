"""Small corpora for the learned-motion tests, written through the real corpus writer.

The motion is the procedural generator's on synthetic dyadic audio (amplitude-modulated tones
taking turns), so it has talking and listening structure, several takes and two speaker styles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from convodrive.audio.source import DyadicAudio
from convodrive.corpus import CorpusWriter, Recording
from convodrive.generators.procedural import ProceduralGenerator

RATE = 16_000


def turn_taking_audio(seconds: float, seed: int) -> np.ndarray:
    """(n, 2) voices taking turns: tones with syllable-rate envelopes, turns of 1-2 s."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = np.arange(n) / RATE
    out = np.zeros((n, 2), np.float32)
    pos, who = 0, int(rng.integers(2))
    while pos < n:
        length = int(rng.uniform(1.0, 2.0) * RATE)
        seg = slice(pos, min(n, pos + length))
        f0 = rng.uniform(110, 220)
        env = 0.5 + 0.5 * np.sin(2 * np.pi * rng.uniform(3, 5) * t[seg])
        out[seg, who] = 0.3 * env * np.sin(2 * np.pi * f0 * t[seg])
        pos += length + int(rng.uniform(0.1, 0.4) * RATE)
        who = 1 - who
    return out


def dyadic_audio(seconds: float, seed: int = 7) -> DyadicAudio:
    """``turn_taking_audio`` as a generator hears it."""
    voices = turn_taking_audio(seconds, seed=seed)
    return DyadicAudio(voices[:, 0], voices[:, 1])


def write_tiny_corpus(
    folder: Path, conversations: int = 6, seconds: float = 4.0, takes: int = 2, seed: int = 0
) -> Path:
    styles = {"calm": {"expressiveness": 0.6}, "lively": {"expressiveness": 1.4}}
    with CorpusWriter(
        folder, source={"command": "tests", "generator": "procedural", "seed": seed}, seed=seed
    ) as writer:
        for i in range(conversations):
            speaker = list(styles)[i % len(styles)]
            audio = turn_taking_audio(seconds, seed * 1000 + i)
            gen = ProceduralGenerator(styles[speaker])
            clips = gen.generate(DyadicAudio(audio[:, 0], audio[:, 1]), seed=i, num_samples=takes)
            writer.add(
                Recording(
                    id=f"conv{i:02d}", audio=audio, takes=clips, speaker=speaker, metadata={"style": styles[speaker]}
                )
            )
    return folder
