"""The one training loop: any recipe, one process or DDP, resumable, deterministic for a seed.

Determinism and resumption come from drawing everything from (seed, step) (``batches.py``):
nothing depends on how many steps ran before in this process, so a resumed run continues exactly
where it stopped, and DDP processes each take their slice of the same global batch. Bad settings
and a run that diverges are one ``UserError`` line; a run that fails before its first checkpoint
leaves nothing in ``--out`` (``run_folder.py``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from convodrive.plumbing.errors import UserError
from convodrive.training import distributed
from convodrive.training.batches import check_batch_fits, default_workers, step_batches, step_seed
from convodrive.training.checkpoint import (
    Checkpoint,
    list_checkpoints,
    load_checkpoint,
    load_optimizer,
    load_weights,
    prune_checkpoints,
    save_checkpoint,
)
from convodrive.training.config import TrainConfig, to_dict
from convodrive.training.heap import keep_freed_blocks
from convodrive.training.logbook import Logbook
from convodrive.training.progress import Progress
from convodrive.training.recipe import Batch, Recipe, StartingPoint, StepContext, TrainingData, to_device
from convodrive.training.registry import get_preset, get_recipe
from convodrive.training.run_folder import check_out, cleaned_if_failed
from convodrive.training.starting_point import init_record, starting_point


class TrainingDiverged(UserError):
    """The loss left the finite numbers: the settings (most often the learning rate) cannot train."""


@dataclasses.dataclass
class TrainRequest:
    model: str
    corpus: Path
    preset: str | None = None
    stage: str | None = None
    out: Path | None = None
    steps: int | None = None
    batch_size: int | None = None
    seed: int | None = None
    device: str = "auto"
    threads: int = 1
    """torch threads per process on the CPU: one by default, as oversubscribed cores make every
    thread spin and wait (measured on a shared 2-core machine: 2 threads ran 9x slower than 1)."""
    progress: bool = True
    workers: int | None = None
    """Processes that assemble the next batches while the model trains; None: none on the CPU (the
    cores train), up to 6 per process on CUDA, whose steps otherwise wait for the batch (an H200 sat
    at 4 to 7 % utilisation on a2p's stages without them)."""
    init: Path | Sequence[Path] | None = None
    """A run or checkpoint of the same model to start from (e.g. its previous stage), or several
    whose weights together are the start (a stage that builds on two others); a run that resumes
    from its own checkpoints ignores it."""
    settings: dict[str, Any] = dataclasses.field(default_factory=dict)
    """Extra overrides of the model config or ``TrainConfig`` (``--set KEY=VALUE``)."""


@dataclasses.dataclass
class TrainResult:
    out: Path
    step: int
    checkpoint: Path | None
    validation: dict[str, float]
    steps_per_second: float


class _LossModule(torch.nn.Module):
    """The network with its recipe's loss as ``forward``, so DDP sees one forward per step."""

    def __init__(self, recipe: Recipe, net: torch.nn.Module) -> None:
        super().__init__()
        self.recipe = recipe
        self.net = net

    def forward(self, batch: Batch, ctx: StepContext) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:  # type: ignore[override]
        return self.recipe.loss(self.net, batch, ctx)


def learning_rate(config: TrainConfig, step: int) -> float:
    """Linear warm-up, then a cosine decay to a tenth over ``decay_steps`` (none when 0)."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    if config.decay_steps <= 0:
        return config.lr
    progress = min(1.0, (step - config.warmup_steps) / config.decay_steps)
    return config.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * progress)))


def _split_settings(recipe: Recipe, settings: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    train_keys = {f.name for f in dataclasses.fields(TrainConfig)}
    model_over = {k: v for k, v in settings.items() if k not in train_keys}
    train_over = {k: v for k, v in settings.items() if k in train_keys}
    return model_over, train_over


def train(request: TrainRequest) -> TrainResult:
    recipe = get_recipe(request.model)
    preset_name, preset = get_preset(recipe, request.preset)
    stage = request.stage or recipe.stages[0]
    if stage not in recipe.stages:
        raise UserError(f"model '{recipe.name}' has no stage '{stage}' (stages: {', '.join(recipe.stages)})")
    model_over, train_over = _split_settings(recipe, request.settings)
    model_cfg = recipe.model_config({**preset.model, **model_over})
    cli_train = {
        k: v
        for k, v in (("steps", request.steps), ("batch_size", request.batch_size), ("seed", request.seed))
        if v is not None
    }
    train_cfg = recipe.train_config({**preset.train, **train_over, **cli_train})
    train_cfg.check()
    corpus = Path(request.corpus)
    out = Path(request.out) if request.out else Path("runs") / f"{recipe.name}-{preset_name}-{stage}"
    check_out(out)

    if request.threads < 1:
        raise UserError(f"--threads must be at least 1, got {request.threads}")
    if request.workers is not None and request.workers < 0:
        raise UserError(f"--workers must be at least 0, got {request.workers}")
    torch.set_num_threads(request.threads)
    keep_freed_blocks()  # each step's activations reuse the last one's pages (training/heap.py)
    procs = distributed.start(request.device)
    try:
        workers = request.workers if request.workers is not None else default_workers(procs)
        inits = [request.init] if isinstance(request.init, (str, Path)) else list(request.init or [])
        identity = _identity(recipe, preset_name, stage, model_cfg, train_cfg)
        with cleaned_if_failed(out, procs.is_main):
            session = _Session.start(recipe, identity, model_cfg, train_cfg, corpus, out, procs, inits)
            return session.run(request.progress, workers)
    finally:
        distributed.stop(procs)


_MAY_CHANGE_ON_RESUME = ("steps", "decay_steps", "log_every", "val_every", "checkpoint_every", "keep_checkpoints")
"""Settings a resumed run may change: how long it runs (a longer run stretches its learning-rate decay
with it, the rate jumping to where the longer schedule has it) and how often it reports."""


def _identity(recipe: Recipe, preset: str, stage: str, model_cfg: Any, train_cfg: TrainConfig) -> dict[str, Any]:
    """What a resumed run must share with the run it continues (the step count may grow)."""
    train = {k: v for k, v in to_dict(train_cfg).items() if k not in _MAY_CHANGE_ON_RESUME}
    return {
        "recipe": recipe.name,
        "preset": preset,
        "stage": stage,
        "model_config": to_dict(model_cfg),
        "train_config": train,
    }


def _resume_point(out: Path, identity: dict[str, Any]) -> Checkpoint | None:
    """The run's latest checkpoint, if any; one of a run with other settings is refused."""
    existing = list_checkpoints(out / "checkpoints")
    if not existing:
        return None
    resume = load_checkpoint(existing[-1])
    before = {k: resume.state.get(k) for k in identity}
    # A setting added after the checkpoint was written (augment) ran at its default there.
    written = {**to_dict(TrainConfig()), **(before["train_config"] or {})}
    before["train_config"] = {k: v for k, v in written.items() if k not in _MAY_CHANGE_ON_RESUME}
    if json.loads(json.dumps(before)) != json.loads(json.dumps(identity)):
        raise UserError(
            f"{out}: holds a run with other settings ({resume.state['recipe']}, preset {resume.state['preset']}); choose another --out"
        )
    return resume


def _build(recipe: Recipe, model_cfg: Any, data: TrainingData, stage: str, device: torch.device) -> torch.nn.Module:
    """The network; one too large to allocate is a ``UserError`` naming the model, not a traceback."""
    try:
        return recipe.build_model(model_cfg, data.spec, stage).to(device)
    except (RuntimeError, MemoryError) as exc:
        if not isinstance(exc, (MemoryError, torch.OutOfMemoryError)) and "alloc" not in str(exc):
            raise
        raise UserError(
            f"model '{recipe.name}': the network of these settings does not fit in memory; choose smaller sizes"
        ) from None


@dataclasses.dataclass
class _Session:
    """One run's network, optimizer and data, from its first (or resumed) step to its last."""

    recipe: Recipe
    identity: dict[str, Any]
    model_cfg: Any
    train_cfg: TrainConfig
    corpus: Path
    out: Path
    procs: distributed.Processes
    data: TrainingData
    net: torch.nn.Module
    optimizer: torch.optim.Optimizer
    step: int
    init: dict[str, Any] | None
    last_checkpoint: Path | None
    validation: dict[str, float] = dataclasses.field(default_factory=dict)

    @classmethod
    def start(
        cls,
        recipe: Recipe,
        identity: dict[str, Any],
        model_cfg: Any,
        train_cfg: TrainConfig,
        corpus: Path,
        out: Path,
        procs: distributed.Processes,
        inits: Sequence[Path],
    ) -> _Session:
        """Everything a run needs before its first step, checked before anything is written."""
        if train_cfg.batch_size % procs.world_size:
            raise UserError(
                f"the global batch size {train_cfg.batch_size} does not split over {procs.world_size} processes"
            )
        stage = identity["stage"]
        resume = _resume_point(out, identity)
        torch.manual_seed(train_cfg.seed)
        data = recipe.load_data(corpus, model_cfg, stage)
        if len(data.train) == 0:
            raise UserError(f"{corpus}: no training examples for model '{recipe.name}'")
        check_batch_fits(data.train, train_cfg.batch_size // procs.world_size, train_cfg.batch_size)
        # After the checks: it imports torch's compiler settings (over a second), which a user's
        # mistake need not wait for.
        torch.use_deterministic_algorithms(True, warn_only=True)
        torch.manual_seed(train_cfg.seed)
        net = _build(recipe, model_cfg, data, stage, procs.device)
        optimizer = torch.optim.AdamW(net.parameters(), lr=train_cfg.lr, weight_decay=train_cfg.weight_decay)
        start: StartingPoint | None = None
        if resume is None:
            start = starting_point(recipe, inits) if inits else None
            recipe.initialise(net, start, data.spec, stage)
        else:
            load_weights(net, resume)
            load_optimizer(optimizer, resume)
        step = resume.step if resume is not None else 0
        return cls(
            recipe,
            identity,
            model_cfg,
            train_cfg,
            corpus,
            out,
            procs,
            data,
            net,
            optimizer,
            step,
            init_record(start, resume),
            resume.path if resume is not None else None,
        )

    def run(self, show_progress: bool, workers: int) -> TrainResult:
        """Train to ``steps``, logging, validating and saving at their intervals."""
        procs, cfg = self.procs, self.train_cfg
        module: torch.nn.Module = _LossModule(self.recipe, self.net)
        if procs.distributed:
            module = torch.nn.parallel.DistributedDataParallel(
                module, device_ids=[procs.device.index] if procs.device.type == "cuda" else None
            )
        if procs.is_main:
            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "run.json").write_text(json.dumps(self._record(), indent=2), encoding="utf-8")
        logbook = Logbook(self.out, enabled=procs.is_main)
        progress = Progress(f"train {self.recipe.name}", cfg.steps, self.step, show_progress and procs.is_main)
        started, first_step = time.monotonic(), self.step
        local_batch = cfg.batch_size // procs.world_size
        try:
            self.net.train()
            for batch in step_batches(
                self.data.train, cfg, procs.rank, local_batch, range(self.step, cfg.steps), workers
            ):
                loss, lr = self._step(module, batch)
                if self.step % cfg.log_every == 0 or self.step == cfg.steps:
                    progress.update(self.step, self._log(logbook, loss, lr))
                if procs.is_main and (self.step % cfg.val_every == 0 or self.step == cfg.steps):
                    self.validation = self._validate(logbook)
                    progress.note(self.step, self.validation)
                if procs.is_main and (self.step % cfg.checkpoint_every == 0 or self.step == cfg.steps):
                    self.last_checkpoint = self._checkpoint()
                distributed.barrier(procs)
        finally:
            progress.close()
            logbook.close()
        elapsed = time.monotonic() - started
        rate = (self.step - first_step) / elapsed if elapsed > 0 and self.step > first_step else 0.0
        return TrainResult(self.out, self.step, self.last_checkpoint, self.validation, rate)

    def _step(self, module: torch.nn.Module, batch: Batch) -> tuple[dict[str, torch.Tensor], float]:
        """One optimiser step; the loss and figures (not yet reduced over processes) and the rate."""
        procs, cfg = self.procs, self.train_cfg
        batch = to_device(batch, procs.device)
        gen = torch.Generator(device="cpu").manual_seed(step_seed(cfg.seed, self.step, procs.rank))
        ctx = StepContext(self.step, procs.rank, procs.world_size, gen)
        lr = learning_rate(cfg, self.step)
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        loss, figures = module(batch, ctx)
        if not torch.isfinite(loss):
            raise TrainingDiverged(
                f"training diverged at step {self.step + 1} (loss {float(loss.detach())}, learning rate {lr:.3g}): "
                "lower the learning rate (--set lr=...) or check the settings"
            )
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(self.net.parameters(), cfg.grad_clip)
        self.optimizer.step()
        self.step += 1
        return {"loss": loss.detach(), **{k: v.detach() for k, v in figures.items()}}, lr

    def _log(self, logbook: Logbook, logged: dict[str, torch.Tensor], lr: float) -> float:
        """Log the step's figures, averaged over processes; the loss."""
        reduced = {
            k: float(distributed.mean_over_processes(v.float().reshape(()), self.procs)) for k, v in logged.items()
        }
        logbook.log(self.step, "train", {**reduced, "lr": lr})
        return reduced["loss"]

    def _validate(self, logbook: Logbook) -> dict[str, float]:
        self.net.eval()
        with torch.no_grad():
            figures = self.recipe.validate(self.net, self.data, self.model_cfg, self.identity["stage"])
        self.net.train()
        logbook.log(self.step, "val", figures)
        return figures

    def _record(self) -> dict[str, Any]:
        """What run.json and every checkpoint's state.json say of the run."""
        return {
            **self.identity,
            "train_config": to_dict(self.train_cfg),
            "corpus": str(self.corpus),
            "init": self.init,
            "world_size": self.procs.world_size,
            "device": str(self.procs.device),
            "torch": torch.__version__,
            "python": platform.python_version(),
        }

    def _checkpoint(self) -> Path:
        record = self._record()
        state = {k: record[k] for k in (*self.identity, "train_config", "corpus", "init", "world_size", "torch")}
        state.update(step=self.step, validation=self.validation)
        ckpt_dir = self.out / "checkpoints"
        path = save_checkpoint(ckpt_dir, self.net, self.optimizer, self.data.spec, state)
        prune_checkpoints(ckpt_dir, self.train_cfg.keep_checkpoints)
        return path
