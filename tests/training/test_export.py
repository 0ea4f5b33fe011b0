"""convodrive export: parity of ONNX Runtime with torch at several sizes, int8 cost, model folders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import cli_in_process, require, run_cli

pytestmark = [require("torch"), require("onnxruntime")]

import torch  # noqa: E402

from convodrive.neural import Graph, load_model_folder  # noqa: E402
from convodrive.plumbing.errors import UserError  # noqa: E402
from convodrive.training.export import PARITY_TOLERANCE, export_graph, parity, restore  # noqa: E402
from convodrive.training.recipe import GraphSpec  # noqa: E402


@pytest.fixture
def fgd_run(tiny_fgd_run: Path) -> Path:
    return tiny_fgd_run


def test_export_checks_parity_at_three_sizes_and_writes_a_verified_folder(fgd_run: Path, tmp_path: Path) -> None:
    out = run_cli("export", str(fgd_run), "--out", str(tmp_path / "model"))
    assert out.returncode == 0, out.stderr
    meta = json.loads((tmp_path / "model" / "model.json").read_text())
    assert set(meta["graphs"]) == {"encoder_holistic", "encoder_body", "encoder_face"}
    for errs in meta["parity"]["max_abs_err"].values():
        assert len(errs) >= 3 and max(errs.values()) <= PARITY_TOLERANCE
    assert meta["features"]["layout"]["dim"] == 330 and meta["training"]["steps"] == 10
    assert "Model card: fgd" in (tmp_path / "model" / "MODEL_CARD.md").read_text()
    # The run and its corpus lie in this machine's temporary folder: model.json names neither path.
    assert str(tmp_path.parent.parent) not in (tmp_path / "model" / "model.json").read_text()
    assert meta["training"]["checkpoint"].startswith("step-") and "path" not in meta["features"]["corpus"]

    # The runtime's features equal torch's at a size the exporter never saw.
    folder = load_model_folder(tmp_path / "model")
    _, _, config, _, net = restore(fgd_run)
    rng = np.random.default_rng(5)
    motion = rng.standard_normal((11, config.window, 330)).astype(np.float32)
    mask = np.ones((11, 1, 330), np.float32)
    got = Graph(folder.graph_path("encoder_face"))(motion=motion, mask=mask)["features"]
    with torch.no_grad():
        want = net.nets["face"].encode(torch.from_numpy(motion[:, :, net.parts["face"]])).numpy()
    assert got.shape == (11, config.latent) and np.abs(got - want).max() <= PARITY_TOLERANCE


def test_an_int8_export_keeps_the_graphs_named_float(fgd_run: Path, tmp_path: Path) -> None:
    out = run_cli("export", str(fgd_run), "--out", str(tmp_path / "mixed"), "--int8", "--float", "encoder_face")
    assert out.returncode == 0, out.stderr
    meta = json.loads((tmp_path / "mixed" / "model.json").read_text())
    assert meta["graphs"]["encoder_face"]["file"] == "encoder_face.onnx"
    assert meta["graphs"]["encoder_body"]["file"] == "encoder_body.int8.onnx"
    assert set(meta["int8"]["cost"]) == {"encoder_body", "encoder_holistic"} and meta["int8"]["float"] == [
        "encoder_face"
    ]
    assert sorted(p.name for p in (tmp_path / "mixed").glob("*.onnx")) == [
        "encoder_body.int8.onnx",
        "encoder_face.onnx",
        "encoder_holistic.int8.onnx",
    ]
    folder = load_model_folder(tmp_path / "mixed")  # its hashes check out
    assert folder.graph_path("encoder_face").name == "encoder_face.onnx"
    assert "kept float: `encoder_face`" in (tmp_path / "mixed" / "MODEL_CARD.md").read_text()
    # An int8 graph quantises its MatMuls, measured against the float graph; convolutions stay float.
    assert 0 < meta["int8"]["cost"]["encoder_body"]["relative_rms_err"] < 0.1
    import onnx

    ops = {n.op_type for n in onnx.load(str(tmp_path / "mixed" / "encoder_body.int8.onnx")).graph.node}
    assert "MatMulInteger" in ops or "DynamicQuantizeLinear" in ops
    assert "ConvInteger" not in ops


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--int8", "--float", "encoder_hands"], "--float encoder_hands: no such graph in fgd's"),
        (["--float", "encoder_face"], "--float names the graphs an int8 export keeps float: it needs --int8"),
    ],
)
def test_a_wrong_float_list_is_one_line(fgd_run: Path, tmp_path: Path, args: list[str], message: str) -> None:
    out = cli_in_process("export", str(fgd_run), "--out", str(tmp_path / "model"), *args)
    assert out.returncode == 2 and message in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "model").exists()


def test_a_shape_baked_into_a_graph_fails_the_parity_check(tmp_path: Path) -> None:
    class Scale(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return x * 2.0 + x.mean(dim=1, keepdim=True)

    spec = GraphSpec(
        name="baked",
        module=Scale(),
        input_names=("x",),
        output_names=("y",),
        example=lambda size, rng: (torch.from_numpy(rng.standard_normal((1, size, 3)).astype(np.float32)),),
        dynamic={},  # no dynamic axes: the exporter fixes the traced length
    )
    export_graph(spec, tmp_path / "baked.onnx", trace_size=5)
    assert parity(spec, tmp_path / "baked.onnx", sizes=(5,))["size=5"] < 1e-6
    with pytest.raises(UserError, match="baked"):
        parity(spec, tmp_path / "baked.onnx", sizes=(5, 9))


def test_export_mistakes_are_one_line(tmp_path: Path) -> None:
    out = cli_in_process("export", str(tmp_path / "nothing"), "--out", str(tmp_path / "m"))
    assert out.returncode == 2 and "no such checkpoint" in out.stderr and len(out.stderr.splitlines()) == 1
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("mine")
    out = cli_in_process("export", str(tmp_path / "nothing"), "--out", str(tmp_path / "notes"))
    assert out.returncode == 2 and (tmp_path / "notes" / "a.txt").exists()
