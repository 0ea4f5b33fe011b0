"""The metric suite's FD_g by part: a distance shows in the part that differs, and only there."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from convodrive.corpus.reader import Corpus
from convodrive.corpus.stats import feature_stats
from convodrive.eval.suite import PART_COLUMNS, Case, score
from convodrive.motion import representation as rep


def _case(corpus: Corpus, hands_from: np.ndarray | None) -> Case:
    conv = corpus.split("train")[0]
    reference = corpus.window(conv.id, 0, 0, conv.frames).clip()
    features = rep.encode_clip(reference)
    if hands_from is not None:
        features[:, rep.PARTS["hands"]] = hands_from[: len(features), rep.PARTS["hands"]]
    sample = rep.decode(features, base=reference)
    mask = rep.feature_mask(conv.joint_mask, conv.face_mask)
    return Case(conv.id, reference, corpus.audio(conv.id), mask, [sample, sample])


def test_a_sample_that_differs_only_in_its_hands_is_far_only_there(tiny_corpus: Path) -> None:
    corpus = Corpus.open(tiny_corpus)
    stats = feature_stats(corpus, "train")
    same = score([_case(corpus, None)], stats, None)
    assert set(PART_COLUMNS) <= set(same)
    assert all(same[name] is not None and abs(same[name]) < 1e-3 for name in PART_COLUMNS), same
    # The reference's own hands, each channel's motion about its mean doubled: the rest untouched.
    conv = corpus.split("train")[0]
    spread = rep.encode_clip(corpus.window(conv.id, 0, 0, conv.frames).clip())
    hands = spread[:, rep.PARTS["hands"]]
    spread[:, rep.PARTS["hands"]] = 2 * hands - hands.mean(axis=0)
    moved = score([_case(corpus, spread)], stats, None)
    assert moved["FD_g hands"] > 0.01, moved
    assert all(abs(moved[name]) < 1e-3 for name in PART_COLUMNS if name != "FD_g hands"), moved
    assert moved["FD_g body"] > 0.01 and abs(moved["FD_g face"]) < 1e-3
