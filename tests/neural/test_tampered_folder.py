"""Model folders whose model.json structure was tampered with (hashes recomputed where files were
changed, so the sha256 check passes): each is one line naming the folder or file and the
problem, through the learned generators and the CLI, never a traceback."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.conftest import REPO, require, run_cli

pytestmark = [require("onnxruntime")]

from convodrive.generators.a2p.generator import A2PGenerator  # noqa: E402
from convodrive.generators.probtalk.generator import ProbTalkGenerator  # noqa: E402
from convodrive.plumbing.errors import InputFileError  # noqa: E402

SHIPPED = {"probtalk": ProbTalkGenerator, "a2p": A2PGenerator}


def tampered(tmp_path: Path, kind: str, change: str) -> Path:
    """A copy of the shipped ``kind`` folder with ``change`` made and its hashes recomputed."""
    folder = tmp_path / kind
    shutil.copytree(REPO / "convodrive" / "generators" / kind / "model", folder)
    meta = folder / "model.json"
    spec: dict[str, Any] = json.loads(meta.read_text())
    graphs = spec["graphs"]
    if change == "graphs a list":
        spec["graphs"] = []
    elif change == "graph a string":
        graphs["vq_decoder"] = graphs["vq_decoder"]["file"]
    elif change == "no architecture":
        spec["architecture"] = {}
    elif change == "random normalisation":
        (folder / "normalisation.npz").write_bytes(os.urandom(5000))
    elif change == "normalisation of another width":
        np.savez(folder / "normalisation.npz", mean=np.zeros(12), std=np.ones(12))
    elif change == "swapped graphs":
        a, b = folder / graphs["predictor_step"]["file"], folder / graphs["vq_decoder"]["file"]
        data_a, data_b = a.read_bytes(), b.read_bytes()
        a.write_bytes(data_b)
        b.write_bytes(data_a)
    elif change == "missing graph":
        del graphs["vq_decoder"]
    for name in spec["files"] if isinstance(spec["files"], dict) else ():
        spec["files"][name] = hashlib.sha256((folder / name).read_bytes()).hexdigest()
    meta.write_text(json.dumps(spec))
    return folder


@pytest.mark.parametrize(
    ("kind", "change", "where", "problem"),
    [
        ("probtalk", "graphs a list", "model.json", "'graphs' must be an object, not list"),
        ("probtalk", "graph a string", "model.json", "graph 'vq_decoder' must be an object naming its file"),
        ("probtalk", "no architecture", "model.json", "architecture has no 'groups'"),
        ("a2p", "no architecture", "model.json", "architecture has no 'window'"),
        ("probtalk", "random normalisation", "normalisation.npz", "is not a readable .npz"),
        ("probtalk", "normalisation of another width", "normalisation.npz", "'mean' must be (330,) numbers"),
        (
            "probtalk",
            "swapped graphs",
            "predictor_step.int8.onnx",
            "is not graph 'predictor_step': its inputs are codes, model.json describes tokens",
        ),
        ("probtalk", "missing graph", "probtalk", "stage export without vq_decoder: export the predictor or refiner"),
        ("a2p", "missing graph", "a2p", "stage export without vq_decoder: export the distill stage"),
    ],
)
def test_tampered_structure_is_one_error_naming_the_file(
    tmp_path: Path, kind: str, change: str, where: str, problem: str
) -> None:
    folder = tampered(tmp_path, kind, change)
    with pytest.raises(InputFileError) as caught:
        SHIPPED[kind]({"model": str(folder)})
    assert caught.value.path == str(folder if where == kind else folder / where)
    assert problem in caught.value.problem


def test_drive_with_a_tampered_folder_is_one_line_exit_2(tmp_path: Path) -> None:
    folder = tampered(tmp_path, "probtalk", "graphs a list")
    out = tmp_path / "out"
    result = run_cli(
        "drive",
        str(REPO / "samples" / "dialogue.wav"),
        "--generator",
        "probtalk",
        "-G",
        f"model={folder}",
        "--out",
        str(out),
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip() == f"convodrive: error: {folder / 'model.json'}: 'graphs' must be an object, not list"
    assert not out.exists()
