"""The papers' baselines, made from a corpus alone (no generator): ground truth, random, KNN.

- ``ground-truth``: the other takes of the same conversation (take 0 is the reference every
  method is scored against), so its figures are the floor a generator can reach.
- ``random`` (the papers' Random): motion of random train conversations, cut to the length.
- ``knn`` (the papers' KNN): for each 2 s segment of the test audio, the motion of the train
  segment whose audio features (mean and spread of both voices' log-mel) are nearest; sample k
  takes the k-th nearest, so the samples differ.
"""

from __future__ import annotations

import numpy as np

from convodrive.corpus import ConversationInfo, Corpus
from convodrive.motion.clip import MotionClip

BASELINES = ("ground-truth", "random", "knn")
KNN_SEGMENT = 60
"""Frames per KNN segment (2 s)."""


def _concat(clips: list[MotionClip]) -> MotionClip:
    return MotionClip(
        pose=np.concatenate([c.pose for c in clips]),
        translation=np.concatenate([c.translation for c in clips]),
        face=np.concatenate([c.face for c in clips]),
        vad=np.concatenate([c.vad for c in clips]),
        state=np.concatenate([c.state for c in clips]),
    )


def ground_truth(corpus: Corpus, conv: ConversationInfo, samples: int) -> list[MotionClip] | None:
    """Takes 1..samples of the conversation (cycling when it has fewer); None with a single take."""
    if conv.takes < 2:
        return None
    return [corpus.window(conv.id, 1 + k % (conv.takes - 1), 0, conv.frames).clip() for k in range(samples)]


def random_motion(corpus: Corpus, conv: ConversationInfo, samples: int, rng: np.random.Generator) -> list[MotionClip]:
    train = corpus.split("train")
    out = []
    for _ in range(samples):
        parts, need = [], conv.frames
        while need > 0:
            src = train[int(rng.integers(len(train)))]
            length = min(need, src.frames)
            start = int(rng.integers(src.frames - length + 1))
            parts.append(corpus.window(src.id, int(rng.integers(src.takes)), start, length).clip())
            need -= length
        out.append(_concat(parts))
    return out


def _audio_key(mel: np.ndarray) -> np.ndarray:
    """(T, 2, bands) -> one vector: per-voice band means and spreads."""
    return np.concatenate([mel.mean(axis=0).ravel(), mel.std(axis=0).ravel()])


class KNNIndex:
    """Train segments of ``KNN_SEGMENT`` frames (hop half a segment) keyed by their audio."""

    def __init__(self, corpus: Corpus) -> None:
        self.corpus = corpus
        keys, self.entries = [], []
        for conv in corpus.split("train"):
            mel = corpus.mel(conv.id)
            for start in range(0, conv.frames - KNN_SEGMENT + 1, KNN_SEGMENT // 2):
                keys.append(_audio_key(mel[start : start + KNN_SEGMENT]))
                self.entries.append((conv.id, start))
        self.keys = np.array(keys)
        self.scale = self.keys.std(axis=0) + 1e-6

    def nearest(self, mel: np.ndarray, count: int) -> list[tuple[str, int]]:
        d = np.linalg.norm((self.keys - _audio_key(mel)) / self.scale, axis=1)
        return [self.entries[i] for i in np.argsort(d, kind="stable")[:count]]

    def motion(self, conv: ConversationInfo, samples: int) -> list[MotionClip]:
        mel = self.corpus.mel(conv.id)
        per_sample: list[list[MotionClip]] = [[] for _ in range(samples)]
        for start in range(0, conv.frames, KNN_SEGMENT):
            length = min(KNN_SEGMENT, conv.frames - start)
            for k, (src, src_start) in enumerate(self.nearest(mel[start : start + length], samples)):
                per_sample[k].append(self.corpus.window(src, 0, src_start, length).clip())
        return [_concat(parts) for parts in per_sample]
