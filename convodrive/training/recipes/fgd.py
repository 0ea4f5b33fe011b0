"""Recipe ``fgd``: the motion autoencoders whose features FGD compares (``convodrive.models.fgd``).

Trained on the train split of a corpus (all takes), validated on its val split by reconstruction
error and by the FGD between real val windows and their reconstructions (near zero for a good
embedder). Exported as one encoder graph per part: ``encoder_holistic``, ``encoder_body``,
``encoder_face``; the folder also holds the normalisation the features were computed with.
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from pathlib import Path

import numpy as np
import torch

from convodrive.eval.distribution import frechet_distance
from convodrive.models.fgd import FGDConfig, FGDNetworks, PartEncoder
from convodrive.motion import representation as rep
from convodrive.plumbing.errors import UserError
from convodrive.training.config import Preset
from convodrive.training.recipe import Batch, DataSpec, GraphSpec, Recipe, StepContext, TrainingData
from convodrive.training.windows import window_data


def fgd_parts() -> dict[str, list[int]]:
    """Feature columns of each part: the face, the body, and both (voice activity is left out)."""
    face = list(range(rep.GROUPS["face"].start, rep.GROUPS["face"].stop))
    body = list(range(rep.GROUPS["body"].start, rep.GROUPS["body"].stop))
    return {"holistic": face + body, "body": body, "face": face}


class FGDRecipe(Recipe):
    name = "fgd"
    description = (
        "Motion autoencoders for the Fréchet Gesture Distance (after ProbTalk's evaluator): 90-frame windows "
        "of the normalised representation, 128-d features, one network each for the face, the body and both."
    )
    ModelConfig = FGDConfig
    presets = {
        "paper": Preset(
            "ProbTalk's embedder size: 90-frame windows, 128-d features",
            {},
            {"steps": 6000, "decay_steps": 5900, "batch_size": 64, "lr": 5e-4},
        ),
        "small": Preset(
            "the shipped embedder: narrower convs",
            {"channels": 32},
            {"steps": 3000, "decay_steps": 2900, "batch_size": 32, "lr": 1e-3},
        ),
        "tiny": Preset(
            "for tests: 16-frame windows, a few units",
            {"window": 16, "channels": 4, "latent": 8},
            {"steps": 20, "batch_size": 8, "warmup_steps": 2, "log_every": 5, "val_every": 10, "checkpoint_every": 10},
        ),
    }
    default_preset = "small"

    def load_data(self, corpus: Path, config: FGDConfig, stage: str) -> TrainingData:
        info = {"parts": fgd_parts(), "window": config.window}
        return window_data(corpus, config.window, max(1, config.window // 6), config.window, info, hears_audio=False)

    def build_model(self, config: FGDConfig, spec: DataSpec, stage: str) -> torch.nn.Module:
        for name, low, high in (("window", 8, 3000), ("channels", 1, 4096), ("latent", 1, 4096)):
            value = getattr(config, name)
            if not low <= value <= high:
                raise UserError(f"model 'fgd': --set {name}={value}: must be between {low} and {high}")
        parts = {k: list(v) for k, v in spec.info["parts"].items()}
        return FGDNetworks(parts, config)

    def loss(
        self, model: torch.nn.Module, batch: Batch, ctx: StepContext
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        assert isinstance(model, FGDNetworks)
        return model.reconstruction_loss(batch["motion"], batch["mask"])

    def validate(self, model: torch.nn.Module, data: TrainingData, config: FGDConfig, stage: str) -> dict[str, float]:
        assert isinstance(model, FGDNetworks)
        if data.val is None or len(data.val) < 2:
            return {}
        batch = data.val.batch(np.arange(min(len(data.val), 512)))
        _, figures = model.reconstruction_loss(batch["motion"], batch["mask"])
        out = {k: float(v) for k, v in figures.items()}
        for name, net in model.nets.items():
            x, _ = model.part_input(name, batch["motion"], batch["mask"])
            real = net.encode(x).numpy()
            recon = net.encode(net(x)).numpy()
            out[f"{name}_fgd_recon"] = frechet_distance(recon, real)
        return out

    def export_graphs(self, model: torch.nn.Module, config: FGDConfig, spec: DataSpec, stage: str) -> Seq[GraphSpec]:
        assert isinstance(model, FGDNetworks)
        dim = rep.FEATURE_DIM

        def example(size: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
            motion = torch.from_numpy(rng.standard_normal((size, config.window, dim)).astype(np.float32))
            mask = torch.from_numpy((rng.random((size, 1, dim)) > 0.1).astype(np.float32))
            return motion, mask

        return [
            GraphSpec(
                name=f"encoder_{part}",
                module=PartEncoder(model, part).eval(),
                input_names=("motion", "mask"),
                output_names=("features",),
                example=example,
                dynamic={"motion": {0: "windows"}, "mask": {0: "windows"}},
                description=f"(windows, {config.window}, {dim}) normalised motion and (windows, 1, {dim}) mask -> (windows, {config.latent}) {part} features",
            )
            for part in model.nets
        ]

    def card(self, config: FGDConfig, spec: DataSpec) -> str:
        return (
            f"{self.description}\n\nUse: `convodrive eval compare` embeds non-overlapping {config.window}-frame windows of real "
            "and generated motion (normalised with this folder's `normalisation.npz`) and reports the Fréchet distance of "
            "the features, per part. FGD figures compare only within one embedder: quote this folder's sha256s with them."
        )
