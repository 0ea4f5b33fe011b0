"""The a2p weights shipped in the package: they load verified, fit the package's 30 MB with a card
that says how they were made, which graphs are int8 and what int8 costs, every sampler runs them,
and the motion they make on the bundled dialogue talks with self's voice."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.audio.source import AudioSource, DyadicAudio
from convodrive.eval.behaviour import behaviour_figures
from convodrive.eval.segments import load_segments
from convodrive.generators.a2p.generator import A2PGenerator
from tests.conftest import REPO
from tests.seams import seam_changes

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


def test_every_sampler_runs_the_shipped_graphs() -> None:
    one = AudioSource(REPO / "samples" / "dialogue.wav").read_all()
    clips = {
        sampler: A2PGenerator({"sampler": sampler, "steps": 2}).generate(one, seed=0)[0]
        for sampler in ("distilled", "ddim", "dpm")
    }
    for sampler, clip in clips.items():
        assert abs(clip.num_frames - one.duration * 30) <= 1, sampler
        assert np.isfinite(clip.pose).all() and np.isfinite(clip.face).all(), sampler
        assert np.abs(np.diff(clip.pose, axis=0)).max() > 1e-4, f"{sampler}: the body does not move"
    assert not np.allclose(clips["distilled"].face, clips["ddim"].face), "the teacher and student graphs differ"


@pytest.mark.parametrize("sampler", ["ddim", "dpm"])
def test_the_shipped_model_talks_with_self_and_rests_while_listening(sampler: str) -> None:
    """Issue 13's must-show on the bundled dialogue: the jaw follows self's voice and shuts in self's
    silences, the arms and the head move at least twice as fast while self talks as while it only
    listens. With the guide poses sampled at temperature 1.2 (``GUIDE_TEMPERATURE``) the head's
    ratio is 2.35 here (seed 1: 2.21), and DPM-Solver++ in its 4 and 8 steps gives 2.25 (2.13); at
    temperature 1 it was 1.94 / 2.05 (dpm 1.99 / 2.03), which the test then asked to be 1.9. Speeds
    are pooled over three takes: the guide poses are sampled, and one take in a few gestures
    through a listening turn. The mouth is shut in 93.5-94.4 % of self's silences in every take
    (seeds 0 and 1, both samplers). On real voices (bench/bench_real_voices.py, the worst of four
    one-minute dialogues) the head's ratio is 3.0 clean and 2.6 with bleed (2.48 and 2.61 at 1)."""
    audio = AudioSource(REPO / "samples" / "dialogue.wav").read_all()
    segments = load_segments(REPO / "samples" / "dialogue.json")
    takes = [
        behaviour_figures(clip, audio, segments)
        for clip in A2PGenerator({"sampler": sampler}).generate(audio, seed=0, num_samples=3)
    ]

    def pooled(part: str, key: str) -> float:
        return float(np.mean([figures[part][key] for figures in takes]))

    for figures in takes:
        lips = figures["lip_sync"]
        assert lips["pearson_jaw_vs_self_envelope"] >= 0.6, lips
        assert lips["jaw_closed_when_self_silent"] >= 0.9, lips
        assert figures["voice_activity"]["self_on_when_only_partner_speaks"] <= 0.1, figures["voice_activity"]
    arms = pooled("arms", "mean_speed_self_speaking_deg_s"), pooled("arms", "mean_speed_listening_deg_s")
    assert arms[0] >= 2 * arms[1], arms
    head = (
        pooled("head", "mean_angular_speed_self_speaking_deg_s"),
        pooled("head", "mean_angular_speed_listening_deg_s"),
    )
    assert head[0] >= 2 * head[1], head


def test_the_shipped_model_is_continuous_at_window_seams() -> None:
    """Each window's start is eased onto the motion before it: no frame change at a seam is larger
    than the largest inside a window (issue 13), where the model's own continuation jumped a wrist
    80 degrees at a fifth of the seams. The face takes 8 steps, a third of the default's time: the
    body is the default's to the bit, and the face's windows are eased alike whatever its steps."""
    one = AudioSource(REPO / "samples" / "dialogue.wav").read_all()
    audio = DyadicAudio(np.tile(one.self_voice, 4), np.tile(one.other_voice, 4))  # 100 s: 24 seams
    gen = A2PGenerator({"face_steps": 8})
    clip = gen.generate(audio, seed=0)[0]
    seams, inside = seam_changes(clip.pose, gen.plan.hop)
    assert len(seams) >= 20
    assert seams.max() <= inside.max(), (seams, inside.max())
