"""The papers' baselines, made from a corpus alone (no generator): ground truth, random, KNN.

- ``ground-truth``: the other takes of the same conversation (take 0 is the reference every
  method is scored against), so its figures are the floor a generator can reach.
- ``random`` (the papers' Random): motion of random train conversations, cut to the length.
- ``knn`` (the papers' KNN): for each 2 s segment of the test audio, the motion of the train
  segment whose audio features (mean and spread of both voices' log-mel) are nearest; sample k
  takes the k-th nearest, so the samples differ. Consecutive segments cross-fade over
  ``KNN_BLEND`` frames (in the learning representation's 6D rotations), as anyone splicing motion
  would: a pop at every seam would be scored as the baseline's fault, not its choice of motion.
"""

from __future__ import annotations

import numpy as np

from convodrive.corpus import ConversationInfo, Corpus
from convodrive.motion import representation as rep
from convodrive.motion.clip import MotionClip

BASELINES = ("ground-truth", "random", "knn")
KNN_SEGMENT = 60
"""Frames per KNN segment (2 s)."""
KNN_BLEND = 8
"""Frames over which one KNN segment fades into the next."""


def _concat(clips: list[MotionClip], drop_last: list[int] | None = None) -> MotionClip:
    """The clips end to end; ``drop_last[i]`` frames left off the end of clip i."""
    ends = [c.num_frames - d for c, d in zip(clips, drop_last or [0] * len(clips))]
    return MotionClip(
        pose=np.concatenate([c.pose[:e] for c, e in zip(clips, ends)]),
        translation=np.concatenate([c.translation[:e] for c, e in zip(clips, ends)]),
        face=np.concatenate([c.face[:e] for c, e in zip(clips, ends)]),
        vad=np.concatenate([c.vad[:e] for c, e in zip(clips, ends)]),
        state=np.concatenate([c.state[:e] for c, e in zip(clips, ends)]),
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
    """Train segments of ``KNN_SEGMENT`` frames (hop half a segment) keyed by their audio; each has
    ``KNN_BLEND`` more frames after it to fade into the next segment."""

    def __init__(self, corpus: Corpus) -> None:
        self.corpus = corpus
        keys, self.entries = [], []
        for conv in corpus.split("train"):
            mel = corpus.mel(conv.id)
            for start in range(0, conv.frames - KNN_SEGMENT - KNN_BLEND + 1, KNN_SEGMENT // 2):
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
            tail = KNN_BLEND if start + length < conv.frames else 0
            for k, (src, src_start) in enumerate(self.nearest(mel[start : start + length], samples)):
                per_sample[k].append(self.corpus.window(src, 0, src_start, length + tail).clip())
        return [_crossfade(parts) for parts in per_sample]


def _crossfade(parts: list[MotionClip]) -> MotionClip:
    """Segments laid end to end, each but the last ``KNN_BLEND`` frames longer than its place: those
    frames fade linearly into the next segment's first ones."""
    features = [rep.encode_clip(c) for c in parts]
    out = [features[0]]
    for nxt in features[1:]:
        prev = out.pop()
        body, fade = prev[:-KNN_BLEND], prev[-KNN_BLEND:]
        n = min(KNN_BLEND, len(nxt))  # a conversation's last segment may be shorter than the blend
        weight = ((np.arange(n) + 1) / (KNN_BLEND + 1))[:, None]
        head = nxt.copy()
        head[:n] = (1 - weight) * fade[:n] + weight * nxt[:n]
        out.extend([body, head])
    base = _concat(parts, drop_last=[KNN_BLEND] * (len(parts) - 1) + [0])  # root and legs: not blended
    return rep.decode(np.concatenate(out), base=base, fps=parts[0].fps)
