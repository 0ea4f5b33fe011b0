"""Audio augmentation as a training option: off by default, seeded per (seed, step, example),
applied to a window's log-mel features, and recorded in run.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import require

pytestmark = [require("torch")]

from convodrive.plumbing.errors import UserError  # noqa: E402
from convodrive.training.config import TrainConfig, augmentation  # noqa: E402
from convodrive.training.corpus_data import open_corpus, train_stats  # noqa: E402
from convodrive.training.windows import CorpusWindows  # noqa: E402


def test_augmented_windows_are_seeded_and_differ_from_the_stored_features(tiny_corpus: Path) -> None:
    corpus = open_corpus(tiny_corpus)
    windows = CorpusWindows(corpus, "train", 60, 30, train_stats(corpus))
    idx = np.array([0, 3])
    plain = windows.batch(idx)
    assert augmentation(TrainConfig()) is None  # off by default: the step batch is the plain one
    assert np.array_equal(windows.step_batch(idx, 5, 0, None)["audio"].numpy(), plain["audio"].numpy())
    every = augmentation(TrainConfig(augment="all", augment_p=1.0))
    a = windows.step_batch(idx, 5, 0, every)["audio"].numpy()
    b = windows.step_batch(idx, 5, 0, every)["audio"].numpy()
    c = windows.step_batch(idx, 6, 0, every)["audio"].numpy()
    assert np.array_equal(a, b)
    assert np.abs(a - c).mean() > 0.1 and np.abs(a - plain["audio"].numpy()).mean() > 0.1
    assert np.array_equal(windows.step_batch(idx, 5, 0, every)["motion"].numpy(), plain["motion"].numpy())
    # With nothing applied, the features are the stored ones.
    none = augmentation(TrainConfig(augment="noise", augment_p=0.0))
    assert np.array_equal(windows.step_batch(idx, 5, 0, none)["audio"].numpy(), plain["audio"].numpy())


def test_an_unknown_kind_is_one_line() -> None:
    with pytest.raises(UserError, match="augment=echo: unknown augmentation 'echo'"):
        TrainConfig(augment="echo").check()


@pytest.mark.timeout(300)
def test_a_tiny_run_with_augmentation_records_it_in_run_json(tiny_corpus: Path, tmp_path: Path) -> None:
    from convodrive.training.loop import TrainRequest, train

    settings = {"augment": "bleed,telephone,noise", "augment_p": 0.8}
    train(
        TrainRequest(
            "fgd",
            tiny_corpus,
            preset="tiny",
            steps=2,
            out=tmp_path / "run",
            device="cpu",
            progress=False,
            settings=settings,
        )
    )
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["train_config"]["augment"] == "bleed,telephone,noise"
    assert record["train_config"]["augment_p"] == 0.8
