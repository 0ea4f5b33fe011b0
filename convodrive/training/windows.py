"""Fixed-length windows of a corpus split as training examples, read lazily from the shards.

An example is (conversation, take, start); a batch reads its windows through the corpus's memory
maps and encodes them in the learning representation, so a corpus of any size costs only its
index in memory.
"""

from __future__ import annotations

import numpy as np
import torch

from convodrive.corpus import Corpus
from convodrive.motion.representation import FeatureStats
from convodrive.training.recipe import Batch, Examples


class CorpusWindows(Examples):
    """Every ``window``-frame stretch starting at a multiple of ``hop``, of every take (or the
    first ``takes``) of every conversation of ``split``.

    A batch holds ``motion`` (B, window, D) normalised features, ``mask`` (B, 1, D) 0/1 for the
    channels the corpus has, ``audio`` (B, window, 2, bands) log-mel of self and partner, and
    ``speaker`` (B,) the speaker's index in the corpus's sorted speaker list.
    """

    def __init__(
        self, corpus: Corpus, split: str, window: int, hop: int, stats: FeatureStats, takes: int | None = None
    ) -> None:
        self.corpus, self.window, self.stats = corpus, window, stats
        self.convs = corpus.split(split)
        rows = [
            (ci, take, start)
            for ci, conv in enumerate(self.convs)
            for take in range(conv.takes if takes is None else min(takes, conv.takes))
            for start in range(0, conv.frames - window + 1, hop)
        ]
        self.index = np.array(rows, np.int64).reshape(-1, 3)

    def __len__(self) -> int:
        return len(self.index)

    def batch(self, indices: np.ndarray) -> Batch:
        motion, mask, audio, speaker = [], [], [], []
        for ci, take, start in self.index[np.asarray(indices, np.int64)]:
            conv = self.convs[ci]
            w = self.corpus.window(conv.id, int(take), int(start), self.window)
            motion.append(self.stats.normalise(w.features()))
            mask.append(w.feature_mask()[None, :])
            audio.append(w.mel)
            speaker.append(self.corpus.speaker_index(conv.speaker))
        return {
            "motion": torch.from_numpy(np.stack(motion)),
            "mask": torch.from_numpy(np.stack(mask).astype(np.float32)),
            "audio": torch.from_numpy(np.stack(audio).astype(np.float32)),
            "speaker": torch.tensor(speaker, dtype=torch.long),
        }
