"""The recipe of ``tiny_learned``: a conv net from log-mel and known context to motion (torch)."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch import nn

from convodrive.motion import representation as rep
from convodrive.training.config import Preset
from convodrive.training.corpus_data import corpus_facts, open_corpus, train_stats
from convodrive.training.recipe import DataSpec, GraphSpec, Recipe, TrainingData
from convodrive.training.windows import CorpusWindows

WINDOW, CONTEXT = 30, 6


@dataclasses.dataclass(frozen=True)
class TinyConfig:
    hidden: int = 16


class TinyRegressor(nn.Module):
    def __init__(self, bands: int, hidden: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv1d(2 * bands + rep.FEATURE_DIM + 1, hidden, 3, padding=1),
            nn.ReLU(),
            nn.Conv1d(hidden, rep.FEATURE_DIM, 3, padding=1),
        )

    def forward(self, audio: torch.Tensor, known: torch.Tensor, known_mask: torch.Tensor) -> torch.Tensor:
        x = torch.cat([audio.flatten(2), known * known_mask, known_mask], dim=-1)
        return self.net(x.transpose(1, 2)).transpose(1, 2)


class TinyRecipe(Recipe):
    name = "tiny_regressor"
    description = "a tiny conv regressor (plugin test)"
    ModelConfig = TinyConfig
    presets = {
        "tiny": Preset(
            "for tests", {}, {"steps": 6, "batch_size": 4, "warmup_steps": 1, "val_every": 3, "checkpoint_every": 3}
        )
    }
    default_preset = "tiny"

    def load_data(self, corpus, config, stage):
        opened = open_corpus(corpus)
        stats = train_stats(opened)
        spec = DataSpec(
            {"layout": rep.layout(), "corpus": corpus_facts(opened)}, {"mean": stats.mean, "std": stats.std}
        )
        return TrainingData(CorpusWindows(opened, "train", WINDOW, 10, stats), None, spec)

    def build_model(self, config, spec, stage):
        return TinyRegressor(int(spec.info["corpus"]["audio_features"]["bands"]), config.hidden)

    def loss(self, model, batch, ctx):
        motion, mask = batch["motion"], batch["mask"]
        known_mask = torch.zeros(motion.shape[0], WINDOW, 1)
        known_mask[:, :CONTEXT] = 1.0
        out = model(batch["audio"], motion, known_mask)
        err = ((out - motion) ** 2 * mask)[:, CONTEXT:]
        return err.sum() / mask.sum().clamp(min=1) / (WINDOW - CONTEXT), {}

    def export_graphs(self, model, config, spec, stage):
        bands = int(spec.info["corpus"]["audio_features"]["bands"])

        def example(size, rng):
            return (
                torch.from_numpy(rng.standard_normal((2, size, 2, bands)).astype(np.float32)),
                torch.from_numpy(rng.standard_normal((2, size, rep.FEATURE_DIM)).astype(np.float32)),
                torch.from_numpy((rng.random((2, size, 1)) > 0.5).astype(np.float32)),
            )

        axes = {0: "takes", 1: "frames"}
        return [
            GraphSpec(
                "step",
                model,
                ("audio", "known", "known_mask"),
                ("motion",),
                example,
                {"audio": axes, "known": axes, "known_mask": axes},
            )
        ]
