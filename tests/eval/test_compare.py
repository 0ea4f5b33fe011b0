"""eval compare: baselines and a generator scored on a corpus split; table, JSON and plot written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.conftest import cli_in_process, require, run_cli

pytestmark = [require("torch"), require("onnxruntime"), require("matplotlib")]


@pytest.fixture
def fgd_model(tiny_fgd_model: Path) -> Path:
    return tiny_fgd_model


def test_compare_writes_the_table_json_and_plot(tiny_corpus: Path, fgd_model: Path, tmp_path: Path) -> None:
    out = run_cli(
        "eval",
        "compare",
        "--corpus",
        str(tiny_corpus),
        "--split",
        "test",
        "--generators",
        "ground-truth,procedural,knn,random",
        "--samples",
        "2",
        "--fgd-model",
        str(fgd_model),
        "--out",
        str(tmp_path / "cmp"),
    )
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert list(data["results"]) == ["ground-truth", "procedural", "knn", "random"]
    for method, figures in data["results"].items():
        for name in ("FD_g body", "FD_g face", "FD_k body", "FGD holistic", "Div_g", "Div_k", "BC", "lip r"):
            assert figures[name] is not None, (method, name)
    # Procedural motion follows the self voice; random train motion does not.
    assert data["results"]["procedural"]["lip r"] > data["results"]["random"]["lip r"] + 0.2
    assert data["results"]["procedural"]["Div_sample"] > 0  # its takes differ by seed
    table = (tmp_path / "cmp" / "compare.md").read_text()
    assert "| knn |" in table and "FD_g body ↓" in table
    assert "## FD_g by part" in table and all(data["results"][m]["FD_g hands"] is not None for m in data["results"])
    png = (tmp_path / "cmp" / "compare.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_a_stratum_scores_only_its_kind_of_conversation(tiny_corpus: Path, fgd_model: Path, tmp_path: Path) -> None:
    """A mixed corpus's test split holds kinds that score apart: ``--stratum`` scores one of them,
    and a kind the split lacks is one line naming those it has."""
    corpus = tmp_path / "mixed"
    shutil.copytree(tiny_corpus, corpus)
    manifest = json.loads((corpus / "manifest.json").read_text())
    convs = manifest["conversations"]
    recorded = next(c for c in convs if c["split"] == "test")
    next(c for c in convs if c["split"] == "train")["split"] = "test"  # a second test conversation
    for c in convs:
        c["stratum"] = "recorded" if c is recorded else "synthesised"
    (corpus / "manifest.json").write_text(json.dumps(manifest))
    tested = sum(c["split"] == "test" for c in convs)
    args = ["eval", "compare", "--corpus", str(corpus), "--generators", "random", "--samples", "1"]
    for kind, count in (("recorded", 1), ("synthesised", tested - 1)):
        out = run_cli(*args, "--stratum", kind, "--fgd-model", str(fgd_model), "--out", str(tmp_path / kind))
        assert out.returncode == 0, out.stderr
        data = json.loads((tmp_path / kind / "compare.json").read_text())
        assert (data["stratum"], data["conversations"]) == (kind, count)
        assert f"test split ({kind}): {count} conversations" in (tmp_path / kind / "compare.md").read_text()
    out = cli_in_process(*args, "--stratum", "paired", "--out", str(tmp_path / "none"))
    assert out.returncode == 2 and len(out.stderr.splitlines()) == 1, out.stderr
    assert "no conversation of kind 'paired' in the test split (kinds there: recorded, synthesised)" in out.stderr
    assert not (tmp_path / "none").exists()


def test_speakers_scores_only_their_conversations(tiny_corpus: Path, fgd_model: Path, tmp_path: Path) -> None:
    """Speaker styles score far apart, so ``--speakers`` scores some alone; a speaker the split lacks
    is one line naming those it has."""
    manifest = json.loads((tiny_corpus / "manifest.json").read_text())
    lively = sum(c["split"] == "train" and c["speaker"] == "lively" for c in manifest["conversations"])
    args = ["eval", "compare", "--corpus", str(tiny_corpus), "--split", "train", "--generators", "random"]
    out = run_cli(
        *args, "--samples", "1", "--speakers", "lively", "--fgd-model", str(fgd_model), "--out", str(tmp_path / "l")
    )
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "l" / "compare.json").read_text())
    assert (data["speakers"], data["conversations"]) == (["lively"], lively) and 0 < lively < 6
    assert f"train split, speakers lively: {lively} conversations" in (tmp_path / "l" / "compare.md").read_text()
    out = cli_in_process(*args, "--speakers", "nobody,noone", "--out", str(tmp_path / "none"))
    assert out.returncode == 2 and len(out.stderr.splitlines()) == 1, out.stderr
    assert "no conversation of speaker nobody, noone in the train split (speakers there: calm, lively)" in out.stderr
    assert not (tmp_path / "none").exists()


def test_an_unknown_method_is_one_line_before_any_work(tiny_corpus: Path, tmp_path: Path) -> None:
    out = cli_in_process(
        "eval",
        "compare",
        "--corpus",
        str(tiny_corpus),
        "--generators",
        "procedural,nosuch",
        "--out",
        str(tmp_path / "c"),
    )
    assert out.returncode == 2 and "unknown generator 'nosuch'" in out.stderr and len(out.stderr.splitlines()) == 1
    assert not (tmp_path / "c").exists()


def test_the_teacher_generator_is_scored_with_each_speakers_style(tiny_corpus: Path) -> None:
    from convodrive.corpus import Corpus
    from convodrive.pipeline.compare import conversation_options

    corpus = Corpus.open(tiny_corpus)
    styles = {conv.speaker: conversation_options("procedural", corpus, conv) for conv in corpus.conversations}
    assert styles == {"calm": {"expressiveness": 0.6}, "lively": {"expressiveness": 1.4}}


def test_one_generator_scored_under_two_labels_with_options_of_its_own(
    tiny_corpus: Path, fgd_model: Path, tmp_path: Path
) -> None:
    out = run_cli(
        "eval",
        "compare",
        "--corpus",
        str(tiny_corpus),
        "--generators",
        "procedural,still=procedural",
        "-G",
        "still.expressiveness=0.0",
        "-G",
        "still.gestures=false",
        "--samples",
        "1",
        "--max-conversations",
        "1",
        "--fgd-model",
        str(fgd_model),
        "--out",
        str(tmp_path / "cmp"),
    )
    assert out.returncode == 0, out.stderr
    results = json.loads((tmp_path / "cmp" / "compare.json").read_text())["results"]
    assert list(results) == ["procedural", "still"]
    # The label's options reached its generator: without expressiveness and gestures it hardly moves.
    assert results["still"]["Div_k"] < 0.5 * results["procedural"]["Div_k"]


@pytest.mark.parametrize(
    ("methods", "options", "message"),
    [
        ("procedural,procedural", [], "'procedural' is named twice"),
        ("procedural,gt=ground-truth", [], "baselines take no label"),
        ("procedural,x=nosuch", [], "unknown generator 'nosuch'"),
        ("procedural,knn", ["-G", "knn.k=3"], "'knn' is not a generator in --generators"),
        ("procedural", ["-G", "other.expressiveness=1"], "'other' is not a generator in --generators"),
        ("procedural", ["-G", "expressiveness=1"], "expected METHOD.KEY=VALUE"),
    ],
)
def test_labels_and_method_options_mistakes_are_one_line(
    tiny_corpus: Path, tmp_path: Path, methods: str, options: list[str], message: str
) -> None:
    out = cli_in_process(
        "eval", "compare", "--corpus", str(tiny_corpus), "--generators", methods, *options, "--out", str(tmp_path / "c")
    )
    assert out.returncode == 2 and message in out.stderr and len(out.stderr.splitlines()) == 1, out.stderr
    assert not (tmp_path / "c").exists()


def test_several_seeds_give_each_figures_mean_and_spread(tiny_corpus: Path, fgd_model: Path, tmp_path: Path) -> None:
    """``--seeds N`` repeats the comparison at N seeds: the table is their mean, the JSON keeps each
    seed's figures (each one what that seed alone scores) and their spread."""
    from convodrive.pipeline.compare import CompareRequest, compare

    common = ["--corpus", str(tiny_corpus), "--generators", "ground-truth,random", "--samples", "2"]
    out = run_cli("eval", "compare", *common, "--seed", "5", "--seeds", "3", "--fgd-model", str(fgd_model),
                  "--out", str(tmp_path / "cmp"))  # fmt: skip
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert data["seeds"] == [5, 6, 7] and [len(runs) for runs in data["per_seed"].values()] == [3, 3]
    for method, runs in data["per_seed"].items():
        for name in ("FD_g body", "FGD holistic", "Div_g"):
            values = [run[name] for run in runs]
            assert data["results"][method][name] == pytest.approx(sum(values) / 3, abs=1e-3), (method, name)
    spread = data["sd_over_seeds"]
    assert spread["ground-truth"]["FD_g body"] == 0.0, "the corpus's own takes do not depend on the seed"
    assert spread["random"]["FD_g body"] > 0.0, "random motion is drawn anew at each seed"
    alone = compare(
        CompareRequest(tiny_corpus, ("ground-truth", "random"), tmp_path / "alone", samples=2, seed=6,
                       fgd_model=fgd_model)
    )  # fmt: skip
    assert alone.results["random"] == data["per_seed"]["random"][1]
    table = (tmp_path / "cmp" / "compare.md").read_text()
    assert "the mean of seeds 5-7" in table and "## Standard deviation over the seeds" in table
    wrong = cli_in_process("eval", "compare", *common, "--seeds", "0", "--out", str(tmp_path / "none"))
    assert wrong.returncode == 2 and "--seeds must be at least 1, got 0" in wrong.stderr
    assert not (tmp_path / "none").exists()
