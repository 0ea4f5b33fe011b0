"""Corpora imported from BEAT2, SHOW, Seamless Interaction and users' own recordings (folders the
importer tests write in those formats) train a tiny model for a few steps without error."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from convodrive.corpus import Corpus
from tests.conftest import require, run_cli
from tests.corpus import sources

pytestmark = [require("torch"), pytest.mark.espeak]

import torch  # noqa: E402
from safetensors.torch import load_file  # noqa: E402

from convodrive.training.loop import TrainRequest, train  # noqa: E402

WRITERS: dict[str, Callable[[Path], Any]] = {
    "beat2": sources.write_beat2,
    "show": sources.write_show,
    "seamless": sources.write_seamless,
}
if hasattr(sources, "write_own"):
    WRITERS["own"] = sources.write_own


@pytest.mark.parametrize("kind", sorted(WRITERS))
def test_an_imported_corpus_trains_a_tiny_model(kind: str, tmp_path: Path) -> None:
    WRITERS[kind](tmp_path / "src")
    imported = run_cli("corpus", "import", kind, str(tmp_path / "src"), "--out", str(tmp_path / "corpus"))
    assert imported.returncode == 0, imported.stderr
    assert Corpus.open(tmp_path / "corpus").split("train")
    result = train(
        TrainRequest(
            "fgd", tmp_path / "corpus", preset="tiny", steps=3, out=tmp_path / "run", device="cpu", progress=False
        )
    )
    assert result.step == 3 and result.checkpoint is not None
    weights = load_file(str(result.checkpoint / "model.safetensors"))
    assert all(torch.isfinite(w).all() for w in weights.values())
