"""The corpus format: what is written reads back exactly; splits by group; windows; statistics."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from convodrive.audio.logmel import log_mel
from convodrive.corpus import Corpus, CorpusWriter, Recording
from convodrive.corpus.manifest import assign_splits, safe_id
from convodrive.corpus.stats import feature_stats
from convodrive.corpus.writer import prepare
from convodrive.motion import representation
from convodrive.plumbing.errors import UserError
from tests.corpus.conftest import fake_recording


def test_written_corpus_reads_back_exactly(small_corpus: tuple[Path, list[Recording]]) -> None:
    folder, recs = small_corpus
    corpus = Corpus.open(folder)
    assert [c.id for c in corpus.conversations] == [r.id for r in recs]
    assert len(corpus.manifest["shards"]) > 1  # the small shard size split them
    assert corpus.speakers == ["calm", "lively"] and corpus.speaker_index("lively") == 1
    assert abs(corpus.hours - sum(len(r.audio) for r in recs) / 16000 / 3600) < 1e-4
    for rec in recs:
        conv = corpus.conversation(rec.id)
        assert conv.takes == len(rec.takes) and conv.metadata == {"language": "en"}
        for k, clip in enumerate(corpus.takes(rec.id)):
            np.testing.assert_array_equal(clip.pose, rec.takes[k].pose)
            np.testing.assert_array_equal(clip.face, rec.takes[k].face)
            np.testing.assert_array_equal(clip.state, rec.takes[k].state)
        # Audio is stored as 16-bit PCM; the features are those of the stored audio, exactly.
        audio = corpus.audio(rec.id)
        np.testing.assert_allclose(audio.self_voice, rec.audio[:, 0], atol=1 / 32768)
        stereo = np.stack([audio.self_voice, audio.other_voice], 1)
        np.testing.assert_array_equal(corpus.mel(rec.id), log_mel(stereo, conv.frames))
    # Any tool reads a shard with plain NumPy.
    with np.load(folder / corpus.manifest["shards"][0]["path"]) as data:
        first = corpus.manifest["shards"][0]["conversations"][0]
        np.testing.assert_array_equal(data[f"{first}/pose"][0], recs[0].takes[0].pose)
    assert list(corpus.check()) == corpus.conversations


def test_splits_are_by_group_and_cover_train_val_test(small_corpus: tuple[Path, list[Recording]]) -> None:
    folder, _ = small_corpus
    corpus = Corpus.open(folder)
    assert corpus.conversation("d0-a").split == corpus.conversation("d0-b").split
    assert all(corpus.split(s) for s in ("train", "val", "test"))
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["splits"] == {s: len(corpus.split(s)) for s in ("train", "val", "test")}
    groups = [f"g{i}" for i in range(40)]
    a = assign_splits(groups, seed=5)
    assert a == assign_splits(list(reversed(groups)), seed=5)  # order-free
    assert a != assign_splits(groups, seed=6)
    assert sorted(a.values()).count("test") == 4 and sorted(a.values()).count("val") == 4
    fixed = assign_splits(groups, seed=5, fixed={"g3": "test"})
    assert fixed["g3"] == "test"
    assert assign_splits(["only"], seed=0) == {"only": "train"}


def test_a_stratum_keeps_its_splits_whatever_else_the_corpus_holds(tmp_path: Path) -> None:
    """Recorded voices added to a synthesised corpus leave every synthesised conversation in its
    split: a model trained on the mixed corpus must not have learned the first one's test split."""

    def splits(folder: Path, recs: list[Recording]) -> dict[str, str]:
        with CorpusWriter(folder, {"kind": "test"}, seed=3) as writer:
            for rec in recs:
                writer.add(rec)
        return {c.id: c.split for c in Corpus.open(folder).conversations}

    def made(prefix: str, count: int, stratum: str) -> list[Recording]:
        return [
            dataclasses.replace(fake_recording(f"{prefix}{i}", 0.2, takes=1), stratum=stratum) for i in range(count)
        ]

    alone = splits(tmp_path / "alone", made("conv", 20, "synthesised"))
    mixed = splits(tmp_path / "mixed", made("conv", 20, "synthesised") + made("pair", 10, "paired"))
    assert {k: v for k, v in mixed.items() if k.startswith("conv")} == alone
    assert sorted(v for k, v in mixed.items() if k.startswith("pair")).count("test") == 1  # drawn among themselves
    strata = {c.id: c.stratum for c in Corpus.open(tmp_path / "mixed").conversations}
    assert {k: v for k, v in strata.items() if k.startswith("pair")} == {f"pair{i}": "paired" for i in range(10)}
    unstratified = splits(tmp_path / "one", made("conv", 20, "") + made("pair", 10, ""))
    assert {k: v for k, v in unstratified.items() if k.startswith("conv")} != alone  # what a single draw did


def test_windows_are_slices_and_sampling_is_seeded(small_corpus: tuple[Path, list[Recording]]) -> None:
    folder, recs = small_corpus
    corpus = Corpus.open(folder)
    rec = recs[4]
    w = corpus.window(rec.id, 1, 17, 60)
    np.testing.assert_array_equal(w.pose, rec.takes[1].pose[17:77])
    np.testing.assert_array_equal(w.vad, rec.takes[1].vad[17:77])
    assert w.mel.shape == (60, 2, 80) and w.speaker == "lively"
    np.testing.assert_array_equal(w.features(), representation.encode_clip(w.clip()))
    assert w.feature_mask().all()
    picks = corpus.sample_windows("train", 50, 20, np.random.default_rng(0))
    again = corpus.sample_windows("train", 50, 20, np.random.default_rng(0))
    assert [(p.conversation, p.take, p.start) for p in picks] == [(p.conversation, p.take, p.start) for p in again]
    train = {c.id: c for c in corpus.split("train")}
    for p in picks:
        assert p.conversation in train and p.start + 50 <= train[p.conversation].frames
        assert p.pose.shape == (50, 55, 3)
    with pytest.raises(UserError, match="outside conversation"):
        corpus.window(rec.id, 0, 170, 60)
    # Raw samples of a window, for front-ends that hear audio itself: frame k is samples [k*1600/3, ...).
    samples = corpus.samples(rec.id, 17, 60)
    assert samples.shape == (int(77 * 1600 / 3) - int(17 * 1600 / 3), 2)
    np.testing.assert_allclose(samples[:, 0], rec.audio[int(17 * 1600 / 3) : int(77 * 1600 / 3), 0], atol=1 / 32768)
    assert corpus.samples(rec.id, 180, 3).shape == (1600, 2)
    with pytest.raises(UserError, match="no train conversation is 100000 frames long"):
        corpus.sample_windows("train", 100_000, 1, np.random.default_rng(0))


def test_masks_travel_and_statistics_skip_them(tmp_path: Path) -> None:
    hands = tuple(representation.PART_JOINTS["hands"])
    recs = [fake_recording(f"c{i}", 2.0, seed=i) for i in range(3)]
    recs[1].missing_joints = hands
    recs[1].missing_face = ("jawOpen",)
    recs[1].split = "train"
    recs[0].split = "train"
    recs[2].split = "test"
    with CorpusWriter(tmp_path / "c", {"kind": "test"}) as writer:
        for rec in recs:
            writer.add(rec)
    corpus = Corpus.open(tmp_path / "c")
    conv = corpus.conversation("c1")
    assert conv.missing_joints == hands and conv.missing_face == ("jawOpen",)
    mask = corpus.window("c1", 0, 0, 10).feature_mask()
    assert not mask[representation.PARTS["hands"]].any() and mask[representation.PARTS["upper"]].all()
    stats = feature_stats(corpus, "train")
    frames = [c.frames * c.takes for c in corpus.split("train")]
    assert stats.count[representation.PARTS["upper"].start] == sum(frames)
    assert stats.count[representation.PARTS["hands"].start] == frames[0]
    only_c0 = np.concatenate([representation.encode_clip(t) for t in corpus.takes("c0")])
    np.testing.assert_allclose(
        stats.mean[representation.PARTS["hands"]], only_c0[:, representation.PARTS["hands"]].mean(0), atol=1e-6
    )


def test_writer_refuses_a_used_folder_and_leaves_nothing_when_it_fails(tmp_path: Path) -> None:
    used = tmp_path / "used"
    used.mkdir()
    (used / "keep.txt").write_text("mine")
    with pytest.raises(UserError, match="not an empty folder"):
        CorpusWriter(used, {"kind": "test"})
    assert sorted(p.name for p in used.iterdir()) == ["keep.txt"]
    out = tmp_path / "new"
    bad = fake_recording("c2", 2.0)
    bad.takes = [bad.takes[0], fake_recording("x", 3.0).takes[0]]  # a take of the wrong length
    with pytest.raises(ValueError, match="take 1 has 90 frames, its audio 60"):
        with CorpusWriter(out, {"kind": "test"}, shard_bytes=1) as writer:
            writer.add(fake_recording("c0", 2.0))
            writer.add(fake_recording("c1", 2.0))
            writer.add(bad)
    assert not out.exists()


def test_ids_are_checked_and_made_safe() -> None:
    assert safe_id("oliver/214542-00_01_17 (take 2).pkl") == "oliver-214542-00_01_17-take-2-.pkl"
    with pytest.raises(ValueError, match="conversation id"):
        prepare(fake_recording("../escape", 1.0))
