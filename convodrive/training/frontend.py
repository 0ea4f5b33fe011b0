"""The wav2vec 2.0 front-end as a graph of a model folder: a recipe that hears through it lists
``frontend_graph(...)`` among its ``export_graphs``, so the runtime runs it in ONNX Runtime."""

from __future__ import annotations

import numpy as np
import torch

from convodrive.models.wav2vec import Wav2VecFrontEnd
from convodrive.training.recipe import GraphSpec


def frontend_graph(front_end: Wav2VecFrontEnd, name: str = "audio_frontend") -> GraphSpec:
    """(batch, samples) 16 kHz audio -> (batch, samples * 3 // 1600, hidden), parity-checked at
    0.5 s, 1.3 s and 2.1 s (the exporter must not keep the traced length)."""

    def example(samples: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        return (torch.from_numpy((0.1 * rng.standard_normal((1, samples))).astype(np.float32)),)

    return GraphSpec(
        name=name,
        module=front_end,
        input_names=("audio",),
        output_names=("features",),
        example=example,
        dynamic={"audio": {1: "samples"}},
        parity_sizes=(8000, 20800, 33601),
        description=f"wav2vec 2.0 hidden states ({front_end.hidden_size}-d) resampled to 30 fps",
    )
