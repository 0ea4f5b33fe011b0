"""The FGD embedder shipped in the package: it loads verified, and it tells motion from non-motion."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.source import DyadicAudio
from convodrive.eval.fgd import SHIPPED, FGDEmbedder
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.motion import representation as rep
from tests.corpora import turn_taking_audio

pytestmark = pytest.mark.onnxruntime


def test_the_shipped_embedder_ranks_another_take_closer_than_broken_motion() -> None:
    assert (SHIPPED / "MODEL_CARD.md").is_file(), "shipped weights come with their card"
    embedder = FGDEmbedder()  # verifies every file's sha256
    # 4.5 minutes: 90 windows of 90 frames, enough for the Fréchet distance's covariances.
    audio = turn_taking_audio(270, 7)
    generated = ProceduralGenerator().generate(DyadicAudio(audio[:, 0], audio[:, 1]), seed=0, num_samples=2)
    real, other = (rep.encode_clip(clip) for clip in generated)
    mask = np.ones(rep.FEATURE_DIM, np.float32)
    rng = np.random.default_rng(0)
    scrambled = other[rng.permutation(len(other))]  # the same frames, in no order
    frozen = np.repeat(other[:1], len(other), 0) + 1e-3 * rng.standard_normal(other.shape)  # a statue
    for part in ("holistic", "body", "face"):
        same = embedder.fgd([other], [real], [mask], part)
        assert same is not None
        for broken in (scrambled, frozen):
            assert embedder.fgd([broken], [real], [mask], part) > 2 * same, part
