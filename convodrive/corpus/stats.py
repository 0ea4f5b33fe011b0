"""Normalisation statistics of the learning features over a corpus split."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from convodrive.corpus.reader import Corpus
from convodrive.motion import representation
from convodrive.motion.representation import FeatureStats

_BLOCK = 4096


def feature_stats(corpus: Corpus, split: str = "train") -> FeatureStats:
    """Per-dimension mean and spread of every take of every conversation in ``split``, each
    conversation's missing channels left out (``representation.feature_mask``)."""

    def batches() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for conv in corpus.split(split):
            mask = representation.feature_mask(conv.joint_mask, conv.face_mask)
            for take in range(conv.takes):
                for start in range(0, conv.frames, _BLOCK):
                    length = min(_BLOCK, conv.frames - start)
                    yield corpus.window(conv.id, take, start, length).features(), mask

    return FeatureStats.fit(batches())
