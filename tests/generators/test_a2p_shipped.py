"""The a2p weights shipped in the package: they load verified, fit the package's 30 MB with a card
that says how they were made, which graphs are int8 and what int8 costs, and both samplers run them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.audio.source import AudioSource
from convodrive.generators.a2p import A2PGenerator
from tests.conftest import REPO

pytestmark = pytest.mark.onnxruntime

SHIPPED = A2PGenerator.shipped_model
assert SHIPPED is not None
LIMIT = 30_000_000
"""Bytes the shipped a2p folder may take (issue 13: at most 30 MB in the package)."""


def test_the_shipped_folder_is_verified_small_enough_and_carded() -> None:
    gen = A2PGenerator()  # no model option: the shipped folder, every sha256 checked
    assert Path(gen.folder.path) == SHIPPED and gen.folder.spec["preset"] == "small"
    size = sum(f.stat().st_size for f in SHIPPED.iterdir())
    assert size <= LIMIT, f"{size / 1e6:.1f} MB is more than the {LIMIT / 1e6:.0f} MB the package ships"
    card = (SHIPPED / "MODEL_CARD.md").read_text()
    for needed in ("scripts/train_a2p.sh", "corpus make", "## Licence", "FGD holistic", "knn", "random"):
        assert needed in card, needed
    int8 = gen.folder.spec["int8"]
    graphs = gen.folder.spec["graphs"]
    if int8 is not None:  # what model.json says is int8 (and kept float) is what the folder holds
        kept_float = set(int8.get("float", []))
        assert set(int8["cost"]) | kept_float == set(graphs) and not set(int8["cost"]) & kept_float
        assert all(graphs[g]["file"] == f"{g}.int8.onnx" for g in int8["cost"])
        assert all(graphs[g]["file"] == f"{g}.onnx" for g in kept_float)
        assert "int8" in card and "MatMul" in card


def test_both_samplers_run_the_shipped_graphs() -> None:
    one = AudioSource(REPO / "samples" / "dialogue.wav").read_all()
    clips = {
        sampler: A2PGenerator({"sampler": sampler, "steps": 2}).generate(one, seed=0)[0]
        for sampler in ("distilled", "ddim")
    }
    for sampler, clip in clips.items():
        assert abs(clip.num_frames - one.duration * 30) <= 1, sampler
        assert np.isfinite(clip.pose).all() and np.isfinite(clip.face).all(), sampler
        assert np.abs(np.diff(clip.pose, axis=0)).max() > 1e-4, f"{sampler}: the body does not move"
    assert not np.allclose(clips["distilled"].face, clips["ddim"].face), "the teacher and student graphs differ"
