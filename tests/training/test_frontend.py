"""The optional wav2vec 2.0 front-end: loaded from a local folder only, exported with parity."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import require

pytestmark = [require("torch"), require("onnxruntime"), require("transformers")]

import torch  # noqa: E402
import transformers  # noqa: E402

from convodrive.neural import Graph  # noqa: E402
from convodrive.plumbing.errors import InputFileError  # noqa: E402
from convodrive.training.export import export_graph, parity  # noqa: E402


@pytest.fixture(scope="module")
def wav2vec_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A randomly initialised, small wav2vec 2.0 saved as a user's local copy would be."""
    config = transformers.Wav2Vec2Config(
        hidden_size=32,
        num_hidden_layers=2,
        num_attention_heads=2,
        intermediate_size=64,
        conv_dim=(16,) * 7,
        num_conv_pos_embeddings=16,
        num_conv_pos_embedding_groups=4,
        do_stable_layer_norm=True,
        feat_extract_norm="layer",
    )
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("w2v") / "wav2vec2-small-random"
    transformers.Wav2Vec2Model(config).save_pretrained(folder)
    return folder


def test_loads_offline_and_gives_one_vector_per_motion_frame(
    wav2vec_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from convodrive.models.wav2vec import Wav2VecFrontEnd

    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    front = Wav2VecFrontEnd.from_folder(wav2vec_folder)
    assert os.environ["HF_HUB_OFFLINE"] == "1" and os.environ["TRANSFORMERS_OFFLINE"] == "1"
    with torch.no_grad():
        out = front(torch.zeros(1, 16000))
    assert out.shape == (1, 30, 32)
    assert not any(p.requires_grad for p in front.parameters())


def test_a_folder_without_weights_is_one_line_and_no_download(tmp_path: Path) -> None:
    from convodrive.models.wav2vec import Wav2VecFrontEnd

    with pytest.raises(InputFileError, match="local copy, nothing is downloaded"):
        Wav2VecFrontEnd.from_folder(tmp_path / "facebook" / "wav2vec2-base-960h")


def test_exports_to_onnx_with_parity_at_three_lengths(wav2vec_folder: Path, tmp_path: Path) -> None:
    from convodrive.models.wav2vec import Wav2VecFrontEnd
    from convodrive.training.frontend import frontend_graph

    spec = frontend_graph(Wav2VecFrontEnd.from_folder(wav2vec_folder))
    export_graph(spec, tmp_path / "frontend.onnx", trace_size=16000)
    errors = parity(spec, tmp_path / "frontend.onnx")
    assert len(errors) == 3 and max(errors.values()) <= 1e-4
    features = Graph(tmp_path / "frontend.onnx")(audio=np.zeros((1, 48000), np.float32))["features"]
    assert features.shape == (1, 90, 32)
