"""The learned generators' tiny model folders, each made once per test run and shared by every test
that drives one (making them is most of these tests' time: training, and every graph exported
with its parity checked)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from tests.conftest import built_once

if TYPE_CHECKING:
    from convodrive.training.recipe import GraphSpec


def _untrained_spec(speakers: list[str]):  # type: ignore[no-untyped-def]
    """What a corpus would tell an export (features, statistics, speakers), for fresh weights."""
    from convodrive.audio.logmel import MelSpec
    from convodrive.motion import representation as rep
    from convodrive.training.recipe import DataSpec

    mel = MelSpec()
    return DataSpec(
        info={
            "layout": rep.layout(),
            "corpus": {"name": "none (tests)", "audio_features": mel.to_dict()},
            "speakers": speakers,
        },
        arrays={
            "mean": np.zeros(rep.FEATURE_DIM, np.float32),
            "std": np.ones(rep.FEATURE_DIM, np.float32),
            "count": np.zeros(rep.FEATURE_DIM, np.int64),  # untrained: no data seen, no channel known constant
            "audio_mean": np.full(mel.bands, -8.0, np.float32),
            "audio_std": np.full(mel.bands, 3.0, np.float32),
        },
    )


def torchscript_export(spec: GraphSpec, path: Path) -> None:
    """One graph by torch's TorchScript exporter: 0.3 s a graph, where the dynamo exporter that
    ``convodrive export`` uses takes 6 s (its symbolic shapes) and twelve graphs took two minutes of
    the suite. The same inputs, outputs and dynamic axes, and ``export_model`` checks its parity at
    three sizes as it checks every graph's. The dynamo exporter's a2p graphs are under test in
    tests/training/test_a2p.py (one of each kind) and in the shipped folder's tests."""
    import warnings

    import torch

    from convodrive.training.export import OPSET

    example = spec.example(5, np.random.default_rng(0))
    axes = {name: {int(axis): dim for axis, dim in dims.items()} for name, dims in spec.dynamic.items()}
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporter's deprecation, and its tracer's notes
        torch.onnx.export(
            spec.module, example, str(path), input_names=list(spec.input_names), output_names=list(spec.output_names),
            dynamo=False, dynamic_axes=axes, opset_version=OPSET,
        )  # fmt: skip


@pytest.fixture(scope="session")
def a2p_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """a2p's tiny preset, distill stage, freshly initialised (the runtime's contracts hold whatever
    the weights), exported with parity: twelve graphs, 60-frame windows."""
    from convodrive.training.export import export_untrained

    def build(folder: Path) -> None:
        spec = _untrained_spec(["calm", "lively"])
        export_untrained("a2p", spec, folder / "model", preset="tiny", seed=1, exporter=torchscript_export)

    return built_once(tmp_path_factory, "a2p", build) / "model"


@pytest.fixture(scope="session")
def probtalk_stages(tiny_corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """probtalk's three stages trained on ``tiny_corpus`` (tiny preset), each from the previous, in
    this process, and the last exported with parity (``model``). The CLI's train and export are
    under test in test_probtalk.py's mistakes and the vq export."""
    from convodrive.training.export import export_model
    from convodrive.training.loop import TrainRequest, train

    stages = ("vq", "predictor", "refiner")

    def build(root: Path) -> None:
        previous: Path | None = None
        for stage in stages:
            request = TrainRequest(
                "probtalk", tiny_corpus, preset="tiny", stage=stage, out=root / stage, device="cpu", progress=False,
                init=previous,
            )  # fmt: skip
            train(request)
            previous = root / stage
        export_model(root / "refiner", root / "model")

    root = built_once(tmp_path_factory, "probtalk", build)
    return {name: root / name for name in (*stages, "model")}


@pytest.fixture(scope="session")
def probtalk_model(probtalk_stages: dict[str, Path]) -> Path:
    return probtalk_stages["model"]
