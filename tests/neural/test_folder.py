"""Model folders: every file hash-checked on load, and each kind of damage is one line naming the file."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import require

pytestmark = [require("onnxruntime"), require("torch")]

from convodrive.neural import Graph, SessionOptions, available_devices, load_model_folder  # noqa: E402
from convodrive.plumbing.errors import InputFileError, UserError  # noqa: E402


def _identity_onnx(path: Path) -> None:
    import onnx
    from onnx import TensorProto, helper

    node = helper.make_node("Mul", ["x", "two"], ["y"])
    two = helper.make_tensor("two", TensorProto.FLOAT, [], [2.0])
    graph = helper.make_graph(
        [node],
        "double",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["n"])],
        [two],
    )
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)]), str(path))


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    root = tmp_path / "model"
    root.mkdir()
    _identity_onnx(root / "double.onnx")
    np.savez(root / "normalisation.npz", mean=np.zeros(3), std=np.ones(3))
    files = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in root.iterdir()}
    spec = {
        "format": "convodrive-model",
        "version": 1,
        "model": "double",
        "graphs": {"double": {"file": "double.onnx"}},
        "files": files,
    }
    (root / "model.json").write_text(json.dumps(spec))
    return root


def test_a_good_folder_loads_and_runs(folder: Path) -> None:
    model = load_model_folder(folder)
    assert model.model == "double" and set(model.arrays("normalisation.npz")) == {"mean", "std"}
    graph = Graph(model.graph_path("double"), SessionOptions(threads=1, device="cpu"))
    assert graph.providers == ["CPUExecutionProvider"]
    np.testing.assert_allclose(graph(x=np.arange(4, dtype=np.float32))["y"], [0, 2, 4, 6])
    assert "cpu" in available_devices()


def test_a_missing_file_is_named(folder: Path) -> None:
    (folder / "normalisation.npz").unlink()
    with pytest.raises(InputFileError, match=r"normalisation\.npz: missing from the model folder"):
        load_model_folder(folder)


def test_a_truncated_graph_is_named(folder: Path) -> None:
    data = (folder / "double.onnx").read_bytes()
    (folder / "double.onnx").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputFileError, match=r"double\.onnx: does not match the sha256"):
        load_model_folder(folder)


def test_a_replaced_file_is_named(folder: Path, tmp_path: Path) -> None:
    np.savez(folder / "normalisation.npz", mean=np.ones(3), std=np.ones(3))
    with pytest.raises(InputFileError, match=r"normalisation\.npz: does not match"):
        load_model_folder(folder)


def test_not_a_model_folder(tmp_path: Path, folder: Path) -> None:
    with pytest.raises(InputFileError, match="no such model folder"):
        load_model_folder(tmp_path / "nope")
    (folder / "model.json").write_text("{not json")
    with pytest.raises(InputFileError, match=r"model\.json: is not valid JSON"):
        load_model_folder(folder)


def test_session_options_are_checked() -> None:
    with pytest.raises(UserError, match="threads"):
        SessionOptions(threads=0)
    with pytest.raises(UserError, match="device"):
        SessionOptions(device="tpu")
    if "cuda" not in available_devices():
        with pytest.raises(UserError, match="no CUDA provider"):
            SessionOptions(device="cuda").providers()
        assert SessionOptions(device="auto").providers() == ["CPUExecutionProvider"]
