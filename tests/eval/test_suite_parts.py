"""The metric suite's FD_g by part: a distance shows in the part that differs, and only there."""

from __future__ import annotations

from pathlib import Path

from convodrive.corpus.reader import Corpus
from convodrive.corpus.stats import feature_stats
from convodrive.eval.suite import PART_COLUMNS, Case, score
from convodrive.motion import representation as rep


def _case(corpus: Corpus, hands_spread: float) -> Case:
    """The first train conversation's take 0, scored against a sample that is the same motion with
    each hand channel's motion about its mean scaled by ``hands_spread``."""
    conv = corpus.split("train")[0]
    reference = corpus.window(conv.id, 0, 0, conv.frames).clip()
    features = rep.encode_clip(reference)
    hands = features[:, rep.PARTS["hands"]]
    features[:, rep.PARTS["hands"]] = hands_spread * hands + (1 - hands_spread) * hands.mean(axis=0)
    sample = rep.decode(features, base=reference)
    mask = rep.feature_mask(conv.joint_mask, conv.face_mask)
    return Case(conv.id, reference, corpus.audio(conv.id), mask, [sample, sample])


def test_a_sample_that_differs_only_in_its_hands_is_far_only_there(tiny_corpus: Path) -> None:
    corpus = Corpus.open(tiny_corpus)
    stats = feature_stats(corpus, "train")
    same = score([_case(corpus, 1.0)], stats, None)
    assert set(PART_COLUMNS) <= set(same)
    assert all(same[name] is not None and abs(same[name]) < 1e-3 for name in PART_COLUMNS), same
    moved = score([_case(corpus, 2.0)], stats, None)  # the hands' motion doubled, the rest untouched
    assert moved["FD_g hands"] > 0.01, moved
    assert all(abs(moved[name]) < 1e-3 for name in PART_COLUMNS if name != "FD_g hands"), moved
    assert moved["FD_g body"] > 0.01 and abs(moved["FD_g face"]) < 1e-3
