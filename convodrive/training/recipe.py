"""What a trainable model tells the one training loop: its data, network, loss, validation, export.

A model issue adds a network file in ``convodrive/models/``, a ``Recipe`` subclass (usually in
``training/recipes/``), one line in ``registry.py``, and a generator that reads the exported folder.
The loop, checkpoints, DDP, logging, resumption and export are shared.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from convodrive.audio.augment import Augment
from convodrive.plumbing.errors import UserError
from convodrive.training.config import Preset, TrainConfig

Batch = dict[str, torch.Tensor]
"""Named tensors of one step. A loss draws its randomness on the CPU from the step's generator (the
same numbers on any device) and moves it to the batch's device."""


def to_device(batch: Batch, device: torch.device) -> Batch:
    return {k: v.to(device, non_blocking=True) for k, v in batch.items()}


def model_device(model: torch.nn.Module) -> torch.device:
    return next(model.parameters()).device


@dataclasses.dataclass
class DataSpec:
    """What a model learned from, kept in its checkpoint and model folder.

    ``info`` is JSON (feature layout, corpus name and id, dimensions); ``arrays`` are NumPy arrays
    (normalisation statistics, masks) stored beside it in ``data.npz``.
    """

    info: dict[str, Any]
    arrays: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)


class Examples(abc.ABC):
    """Training examples, addressed by index. The loop draws indices; the recipe makes tensors."""

    @abc.abstractmethod
    def __len__(self) -> int: ...

    @abc.abstractmethod
    def batch(self, indices: np.ndarray) -> Batch:
        """CPU tensors of the examples ``indices`` (the loop moves them to the device)."""

    def step_batch(self, indices: np.ndarray, step: int, seed: int, augment: Augment | None) -> Batch:
        """The batch of training step ``step``: examples that hear audio augment it here (seeded by
        ``(seed, step, example)``); others are the plain ``batch``."""
        return self.batch(indices)


@dataclasses.dataclass
class TrainingData:
    train: Examples
    val: Examples | None
    spec: DataSpec


class GraphModule(torch.nn.Module):
    """One exported graph of a network: ``forward(*inputs)`` is ``call(owner, *inputs)``. ``owner``
    is a submodule, so the exporter sees the weights ``call`` reads; a graph of a method or of a
    few lines around it needs no class of its own."""

    def __init__(self, owner: torch.nn.Module, call: Callable[..., Any]) -> None:
        super().__init__()
        self.owner = owner
        self.call = call

    def forward(self, *inputs: torch.Tensor) -> Any:
        return self.call(self.owner, *inputs)


@dataclasses.dataclass(frozen=True)
class GraphSpec:
    """One ONNX graph to export, and how to feed it for the parity check.

    ``example(size, rng)`` returns the inputs at one size (a sequence length, or a number of
    windows); export checks torch against ONNX Runtime at every size in ``parity_sizes``, so a
    shape the exporter baked in is caught. ``dynamic`` maps an input name to {axis: axis name};
    ``"8*tokens"`` names an axis that is always 8 times the dimension ``tokens``.
    """

    name: str
    module: torch.nn.Module
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    example: Callable[[int, np.random.Generator], tuple[torch.Tensor, ...]]
    dynamic: dict[str, dict[int, str]]
    parity_sizes: tuple[int, ...] = (1, 7, 33)
    description: str = ""
    float_from: tuple[str, ...] = ()
    """Inputs whose first matrix products int8 export leaves in float (``quantise_int8``)."""


@dataclasses.dataclass
class StartingPoint:
    """The weights of another run that a new run starts from (``--init``), e.g. the previous stage
    of a model trained in stages. ``spec`` is the data that run learned from."""

    path: Path
    stage: str
    step: int
    weights: dict[str, torch.Tensor]
    spec: DataSpec


@dataclasses.dataclass(frozen=True)
class StepContext:
    """Per-step facts a loss may use. ``generator`` is seeded by (seed, step, rank): resumable."""

    step: int
    rank: int
    world_size: int
    generator: torch.Generator


class Recipe(abc.ABC):
    name: ClassVar[str]
    description: ClassVar[str]
    ModelConfig: ClassVar[type]
    """A frozen dataclass of the network's hyper-parameters."""
    presets: ClassVar[dict[str, Preset]]
    default_preset: ClassVar[str]
    stages: ClassVar[tuple[str, ...]] = ("main",)
    """Models trained in stages (e.g. VQ, then predictor) name them; ``--stage`` picks one."""

    def model_config(self, overrides: dict[str, Any]) -> Any:
        from convodrive.training.config import with_overrides

        return with_overrides(self.ModelConfig(), overrides, f"model '{self.name}'")

    def train_config(self, overrides: dict[str, Any]) -> TrainConfig:
        from convodrive.training.config import with_overrides

        return with_overrides(TrainConfig(), overrides, f"model '{self.name}' training")

    @abc.abstractmethod
    def load_data(self, corpus: Path, config: Any, stage: str) -> TrainingData:
        """The train (and val) examples of ``corpus``; ``UserError`` for a corpus it cannot use."""

    @abc.abstractmethod
    def build_model(self, config: Any, spec: DataSpec, stage: str) -> torch.nn.Module: ...

    def initialise(self, model: torch.nn.Module, start: StartingPoint | None, spec: DataSpec, stage: str) -> None:
        """Set a new run's first weights (not called when a run resumes). Default: with ``--init``,
        copy every tensor whose name and shape match; a start that shares none is a mistake. A
        recipe whose later stages need an earlier one's weights says so here."""
        if start is None:
            return
        own = model.state_dict()
        matched = {k: v for k, v in start.weights.items() if k in own and own[k].shape == v.shape}
        if not matched:
            raise UserError(f"--init {start.path}: shares no weights with model '{self.name}' ({stage} stage)")
        model.load_state_dict(matched, strict=False)

    @abc.abstractmethod
    def loss(
        self, model: torch.nn.Module, batch: Batch, ctx: StepContext
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The scalar to minimise and named figures to log (detached or not; the loop detaches)."""

    def validate(self, model: torch.nn.Module, data: TrainingData, config: Any, stage: str) -> dict[str, float]:
        """Figures on the validation examples (no gradients). Default: the mean loss."""
        if data.val is None or len(data.val) == 0:
            return {}
        idx = np.arange(min(len(data.val), 256))
        ctx = StepContext(0, 0, 1, torch.Generator().manual_seed(0))
        loss, _ = self.loss(model, data.val.batch(idx), ctx)
        return {"loss": float(loss)}

    def mean_validation_figures(
        self, model: torch.nn.Module, data: TrainingData, examples: int, chunk: int = 16
    ) -> dict[str, float]:
        """The loss and its figures averaged over chunks of the first ``examples`` validation
        examples, each chunk with its own fixed seed (for recipes whose loss samples noise or masks)."""
        if data.val is None or len(data.val) == 0:
            return {}
        index = np.arange(min(len(data.val), examples))
        chunks = [index[i : i + chunk] for i in range(0, len(index), chunk)]
        totals: dict[str, float] = {}
        for i, part in enumerate(chunks):
            ctx = StepContext(i, 0, 1, torch.Generator().manual_seed(1000 + i))
            loss, figures = self.loss(model, to_device(data.val.batch(part), model_device(model)), ctx)
            for name, value in {"loss": loss, **figures}.items():
                totals[name] = totals.get(name, 0.0) + float(value) / len(chunks)
        return totals

    @abc.abstractmethod
    def export_graphs(self, model: torch.nn.Module, config: Any, spec: DataSpec, stage: str) -> Sequence[GraphSpec]: ...

    def export_arrays(self, model: torch.nn.Module, config: Any, spec: DataSpec) -> dict[str, dict[str, np.ndarray]]:
        """Extra ``.npz`` files for the model folder, by file name. Default: the data spec's arrays."""
        return {"normalisation.npz": dict(spec.arrays)} if spec.arrays else {}

    def card(self, config: Any, spec: DataSpec) -> str:
        """Markdown paragraphs for the model card: what the model is for and how it was made."""
        return self.description
