"""eval compare: baselines and a generator scored on a corpus split; table, JSON and plot written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.conftest import require, run_cli

pytestmark = [require("torch"), require("onnxruntime"), require("matplotlib")]


@pytest.fixture(scope="module")
def fgd_model(tiny_corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fgd_cmp")
    trained = run_cli(
        "train", "fgd", "--corpus", str(tiny_corpus), "--preset", "tiny", "--no-progress", "--out", str(root / "run")
    )
    assert trained.returncode == 0, trained.stderr
    exported = run_cli("export", str(root / "run"), "--out", str(root / "model"))
    assert exported.returncode == 0, exported.stderr
    return root / "model"


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
    png = (tmp_path / "cmp" / "compare.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_an_unknown_method_is_one_line_before_any_work(tiny_corpus: Path, tmp_path: Path) -> None:
    out = run_cli(
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
