"""Fixed-length windows of a corpus split as training examples, read lazily from the shards.

An example is (conversation, take, start); a batch reads its windows through the corpus's memory
maps and encodes them in the learning representation, so a corpus of any size costs only its
index in memory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from convodrive import FPS
from convodrive.audio.augment import Augment
from convodrive.corpus import Corpus, Window
from convodrive.motion import representation as rep
from convodrive.motion.representation import FeatureStats
from convodrive.plumbing.errors import UserError
from convodrive.training.corpus_data import corpus_facts, normalisation_arrays, open_corpus, train_stats
from convodrive.training.recipe import Batch, DataSpec, Examples, TrainingData


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
        return self._batch(indices)

    def step_batch(self, indices: np.ndarray, step: int, seed: int, augment: Augment | None) -> Batch:
        return self._batch(indices, (step, seed, augment) if augment is not None else None)

    def _batch(self, indices: np.ndarray, augmenting: tuple[int, int, Augment] | None = None) -> Batch:
        motion, mask, audio, speaker = [], [], [], []
        for example in np.asarray(indices, np.int64):
            ci, take, start = self.index[example]
            conv = self.convs[ci]
            w = self.corpus.window(conv.id, int(take), int(start), self.window)
            motion.append(self.stats.normalise(w.features()))
            mask.append(w.feature_mask()[None, :])
            if augmenting is None:
                audio.append(w.mel)
            else:
                step, seed, augment = augmenting
                rng = np.random.default_rng([seed, step, int(example)])
                audio.append(self.augmented_mel(w, augment, rng))
            speaker.append(self.corpus.speaker_index(conv.speaker))
        return {
            "motion": torch.from_numpy(np.stack(motion)),
            "mask": torch.from_numpy(np.stack(mask).astype(np.float32)),
            "audio": torch.from_numpy(np.stack(audio).astype(np.float32)),
            "speaker": torch.tensor(speaker, dtype=torch.long),
        }

    def augmented_mel(self, window: Window, augment: Augment, rng: np.random.Generator) -> np.ndarray:
        """(window, 2, bands) log-mel of a window as ``augment`` changes it (in the feature domain:
        ``audio.augment`` says why)."""
        changed, _ = augment(window.mel, rng, self.corpus.mel_spec)
        return changed


def window_data(
    corpus: Path,
    window: int,
    hop: int,
    val_hop: int,
    info: dict[str, Any],
    *,
    hears_audio: bool = True,
    stage: str = "",
) -> TrainingData:
    """A recipe's examples: the train split's windows every ``hop`` frames (every take), the val
    split's every ``val_hop`` (first take), and the spec its model folder keeps: the feature layout,
    the corpus's facts and speakers, ``info``, and the normalisation arrays (the audio's too when
    the model ``hears_audio``). The error for a corpus too short names ``stage`` where one is given."""
    opened = open_corpus(corpus)
    stats = train_stats(opened)
    arrays = normalisation_arrays(stats, opened) if hears_audio else {"mean": stats.mean, "std": stats.std}
    spec = DataSpec(
        info={"layout": rep.layout(), "corpus": corpus_facts(opened), "speakers": list(opened.speakers), **info},
        arrays=arrays,
    )
    train = CorpusWindows(opened, "train", window, hop, stats)
    if len(train) == 0:
        named = f" ({stage} stage)" if stage else ""
        raise UserError(f"{corpus}: no conversation of the train split lasts {window / FPS:.2f} s{named}")
    val = CorpusWindows(opened, "val", window, val_hop, stats, takes=1)
    return TrainingData(train=train, val=val if len(val) else None, spec=spec)
