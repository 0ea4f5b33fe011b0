"""The corpus baselines: KNN splices real motion without a pop at its seams."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from convodrive.corpus.reader import Corpus
from convodrive.eval.baselines import KNN_BLEND, KNN_SEGMENT, KNNIndex
from convodrive.motion import representation as rep


def test_knn_seams_move_no_more_than_the_motion_inside_its_segments(tiny_corpus: Path) -> None:
    corpus = Corpus.open(tiny_corpus)
    index = KNNIndex(corpus)
    seam, inside = [], []
    for conv in corpus.split("test") + corpus.split("val"):
        clips = index.motion(conv, 2)
        assert [c.num_frames for c in clips] == [conv.frames] * 2
        assert not np.array_equal(clips[0].pose, clips[1].pose), "sample k takes the k-th nearest segment"
        features = rep.encode_clip(clips[0])[:, : rep.PARTS["vad"].start]
        step = np.abs(np.diff(features, axis=0)).max(axis=1)
        seams = np.arange(KNN_SEGMENT - 1, len(step), KNN_SEGMENT)
        seam.extend(step[seams])
        inside.extend(np.delete(step, seams))
    assert seam, "the test conversations are longer than one segment"
    assert np.mean(seam) < 2 * np.mean(inside), (np.mean(seam), np.mean(inside))


def test_knn_covers_a_conversation_whose_last_segment_is_shorter_than_the_blend(tiny_corpus: Path) -> None:
    corpus = Corpus.open(tiny_corpus)
    index = KNNIndex(corpus)
    conv = corpus.split("test")[0]
    frames = KNN_SEGMENT + KNN_BLEND - 3  # the second segment: 5 frames
    assert conv.frames > frames
    short = dataclasses.replace(conv, frames=frames)
    clips = index.motion(short, 2)
    assert [c.num_frames for c in clips] == [frames] * 2
    assert all(np.isfinite(c.pose).all() for c in clips)
