"""What the recipes of networks trained in stages share (``a2p``, ``probtalk``): a network that
standardises the corpus's audio itself, and stages that start from the runs of earlier ones.

A later stage keeps the networks of earlier stages frozen, so it must start (``--init``) from runs
that hold them, trained on the same data (the same normalisation) with the same settings.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from convodrive.plumbing.errors import UserError
from convodrive.training.recipe import DataSpec, Recipe, StartingPoint

NORMALISATION = ("mean", "std", "audio_mean", "audio_std")
"""The data spec's arrays two runs of the same data share."""


def check_same_data(
    theirs: Mapping[str, np.ndarray], ours: Mapping[str, np.ndarray], who: str, keys: Sequence[str] = NORMALISATION
) -> None:
    """One-line error naming ``who`` (the setting or option that brought ``theirs``) unless its
    normalisation arrays ``keys`` are this corpus's: a run learns only from a run of the same data."""
    if any(not np.allclose(theirs[k], ours[k], atol=1e-5) for k in keys):
        raise UserError(f"{who}: learnt from other data (its normalisation differs from this corpus's)")


class StagedRecipe(Recipe):
    @abc.abstractmethod
    def network(self, config: Any, bands: int, speakers: int, stage: str) -> torch.nn.Module:
        """The stage's network, with an ``audio_norm`` whose statistics ``build_model`` sets."""

    @abc.abstractmethod
    def inherited(self, model: torch.nn.Module) -> tuple[str, ...]:
        """The networks ``model``'s stage takes, frozen, from the runs it starts from."""

    def init_hint(self, stage: str) -> str:
        """What ``--init`` a stage needs, for the message of a run that gives none."""
        return "RUN (the previous stage)"

    def after_initialise(self, model: torch.nn.Module, stage: str) -> None:
        """Derive networks from the inherited ones (a student copied from its teacher)."""

    def build_model(self, config: Any, spec: DataSpec, stage: str) -> torch.nn.Module:
        bands = int(spec.info["corpus"]["audio_features"]["bands"])
        model = self.network(config, bands, len(spec.info["speakers"]), stage)
        norm: Any = model.audio_norm
        norm.mean.copy_(torch.from_numpy(spec.arrays["audio_mean"]))
        norm.std.copy_(torch.from_numpy(spec.arrays["audio_std"]))
        return model

    def initialise(self, model: torch.nn.Module, start: StartingPoint | None, spec: DataSpec, stage: str) -> None:
        """A stage starts from the runs of the stages it builds on (``--init``, repeatable): of the
        same data, holding every network it inherits at this model config's shapes."""
        needed = self.inherited(model)
        if not needed:
            super().initialise(model, start, spec, stage)
            return
        if start is None:
            raise UserError(
                f"model '{self.name}': the {stage} stage starts from trained {', '.join(needed)} networks: "
                f"--init {self.init_hint(stage)}"
            )
        check_same_data(start.spec.arrays, spec.arrays, f"--init {start.path}")
        own = model.state_dict()
        for name in needed:
            keys = [k for k in own if k.startswith(f"{name}.")]
            bad = [k for k in keys if k not in start.weights or start.weights[k].shape != own[k].shape]
            if bad:
                raise UserError(
                    f"--init {start.path}: holds no {name} network of these settings (a {start.stage} run; "
                    f"mismatch at {bad[0]}): train that stage first, with the same preset"
                )
        super().initialise(model, start, spec, stage)
        self.after_initialise(model, stage)
