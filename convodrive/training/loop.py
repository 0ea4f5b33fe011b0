"""The one training loop: any recipe, one process or DDP, resumable, deterministic for a seed.

Determinism and resumption come from drawing everything from (seed, step): the examples of step s
are positions ``s*B .. s*B+B-1`` of a sequence of per-epoch permutations seeded by (seed, epoch),
and a loss's randomness comes from a generator seeded by (seed, step, rank). Nothing depends on
how many steps ran before in this process, so a resumed run continues exactly where it stopped,
and DDP processes each take their slice of the same global batch.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from convodrive.plumbing.errors import UserError
from convodrive.training import distributed
from convodrive.training.checkpoint import list_checkpoints, load_checkpoint, prune_checkpoints, save_checkpoint
from convodrive.training.config import TrainConfig, to_dict
from convodrive.training.heap import keep_freed_blocks
from convodrive.training.logbook import Logbook
from convodrive.training.recipe import Batch, Examples, Recipe, StartingPoint, StepContext, TrainingData, to_device
from convodrive.training.registry import get_preset, get_recipe


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


class StepBatches(torch.utils.data.Dataset):
    """The batch of each step, a pure function of the step (module doc), so that worker processes
    can assemble batches ahead and the run stays the same with any number of them."""

    def __init__(self, windows: Examples, config: TrainConfig, rank: int, local_batch: int) -> None:
        self.windows, self.config, self.rank, self.local_batch = windows, config, rank, local_batch

    def __len__(self) -> int:
        return self.config.steps

    def __getitem__(self, step: int) -> Batch:
        indices = batch_indices(self.config.seed, step, len(self.windows), self.config.batch_size)
        return self.windows.batch(indices[self.rank * self.local_batch : (self.rank + 1) * self.local_batch])


def step_batches(
    windows: Examples, config: TrainConfig, rank: int, local_batch: int, steps: range, workers: int
) -> Iterable[Batch]:
    """This process's batches of ``steps``, in order, assembled by ``workers`` processes (0: here)."""
    dataset = StepBatches(windows, config, rank, local_batch)
    if workers == 0:
        return (dataset[s] for s in steps)
    return torch.utils.data.DataLoader(
        dataset,
        batch_size=None,
        sampler=steps,
        num_workers=workers,
        prefetch_factor=4,
        multiprocessing_context="fork",
        generator=torch.Generator(),  # its workers' seeds; drawn from torch's global one, they would move dropout's
    )


def default_workers(procs: distributed.Processes) -> int:
    """See ``TrainRequest.workers``."""
    if procs.device.type != "cuda":
        return 0
    return max(0, min(6, (os.cpu_count() or 1) // procs.world_size - 1))


class _LossModule(torch.nn.Module):
    """The network with its recipe's loss as ``forward``, so DDP sees one forward per step."""

    def __init__(self, recipe: Recipe, net: torch.nn.Module) -> None:
        super().__init__()
        self.recipe = recipe
        self.net = net

    def forward(self, batch: Batch, ctx: StepContext) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:  # type: ignore[override]
        return self.recipe.loss(self.net, batch, ctx)


def batch_indices(seed: int, step: int, count: int, batch_size: int) -> np.ndarray:
    """The example indices of step ``step``: positions of per-epoch permutations (see module doc)."""
    positions = step * batch_size + np.arange(batch_size, dtype=np.int64)
    epochs, offsets = np.divmod(positions, count)
    out = np.empty(batch_size, np.int64)
    for epoch in np.unique(epochs):
        perm = np.random.default_rng([seed, int(epoch)]).permutation(count)
        sel = epochs == epoch
        out[sel] = perm[offsets[sel]]
    return out


def step_seed(seed: int, step: int, rank: int) -> int:
    return int(np.random.SeedSequence([seed, step, rank]).generate_state(1)[0])


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
    if train_cfg.steps < 1 or train_cfg.batch_size < 1:
        raise UserError(f"--steps and --batch-size must be at least 1 (got {train_cfg.steps}, {train_cfg.batch_size})")
    corpus = Path(request.corpus)
    out = Path(request.out) if request.out else Path("runs") / f"{recipe.name}-{preset_name}-{stage}"

    if request.threads < 1:
        raise UserError(f"--threads must be at least 1, got {request.threads}")
    if request.workers is not None and request.workers < 0:
        raise UserError(f"--workers must be at least 0, got {request.workers}")
    torch.set_num_threads(request.threads)
    keep_freed_blocks()  # each step's activations reuse the last one's pages (training/heap.py)
    procs = distributed.start(request.device)
    try:
        workers = request.workers if request.workers is not None else default_workers(procs)
        return _train(
            recipe,
            preset_name,
            stage,
            model_cfg,
            train_cfg,
            corpus,
            out,
            procs,
            request.progress,
            request.init,
            workers,
        )
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


def _train(
    recipe: Recipe,
    preset: str,
    stage: str,
    model_cfg: Any,
    train_cfg: TrainConfig,
    corpus: Path,
    out: Path,
    procs: distributed.Processes,
    show_progress: bool,
    init: Path | Sequence[Path] | None = None,
    workers: int = 0,
) -> TrainResult:
    if train_cfg.batch_size % procs.world_size:
        raise UserError(
            f"the global batch size {train_cfg.batch_size} does not split over {procs.world_size} processes"
        )
    local_batch = train_cfg.batch_size // procs.world_size
    identity = _identity(recipe, preset, stage, model_cfg, train_cfg)
    ckpt_dir = out / "checkpoints"
    existing = list_checkpoints(ckpt_dir)
    resume = load_checkpoint(existing[-1]) if existing else None
    if resume is not None:
        before = {k: resume.state.get(k) for k in identity}
        before["train_config"] = {k: v for k, v in before["train_config"].items() if k not in _MAY_CHANGE_ON_RESUME}
        if json.loads(json.dumps(before)) != json.loads(json.dumps(identity)):
            raise UserError(
                f"{out}: holds a run with other settings ({resume.state['recipe']}, preset {resume.state['preset']}); choose another --out"
            )

    torch.manual_seed(train_cfg.seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    data: TrainingData = recipe.load_data(corpus, model_cfg, stage)
    if len(data.train) == 0:
        raise UserError(f"{corpus}: no training examples for model '{recipe.name}'")
    torch.manual_seed(train_cfg.seed)
    net = recipe.build_model(model_cfg, data.spec, stage).to(procs.device)
    optimizer = torch.optim.AdamW(net.parameters(), lr=train_cfg.lr, weight_decay=train_cfg.weight_decay)
    step = 0
    inits = [init] if isinstance(init, (str, Path)) else list(init or [])
    start = _starting_point(recipe, inits) if resume is None and inits else None
    if resume is None:
        recipe.initialise(net, start, data.spec, stage)
    if resume is not None:
        from convodrive.training.checkpoint import load_weights

        load_weights(net, resume)
        optimizer.load_state_dict(resume.optimizer_state())
        step = resume.step
    module: torch.nn.Module = _LossModule(recipe, net)
    if procs.distributed:
        module = torch.nn.parallel.DistributedDataParallel(
            module, device_ids=[procs.device.index] if procs.device.type == "cuda" else None
        )

    if procs.is_main:
        out.mkdir(parents=True, exist_ok=True)
        run_info = {
            **identity,
            "train_config": to_dict(train_cfg),
            "corpus": str(corpus),
            "init": _init_record(start, resume),
            "world_size": procs.world_size,
            "device": str(procs.device),
            "torch": torch.__version__,
            "python": platform.python_version(),
        }
        (out / "run.json").write_text(json.dumps(run_info, indent=2), encoding="utf-8")
    init_record = _init_record(start, resume)
    logbook = Logbook(out, enabled=procs.is_main)
    progress = _Progress(f"train {recipe.name}", train_cfg.steps, step, show_progress and procs.is_main)
    last_ckpt: Path | None = existing[-1] if existing else None
    validation: dict[str, float] = {}
    started, first_step = time.monotonic(), step

    def checkpoint() -> Path:
        state = {
            **identity,
            "train_config": to_dict(train_cfg),
            "step": step,
            "corpus": str(corpus),
            "init": init_record,
            "world_size": procs.world_size,
            "validation": validation,
            "torch": torch.__version__,
        }
        path = save_checkpoint(ckpt_dir, net, optimizer, data.spec, state)
        prune_checkpoints(ckpt_dir, train_cfg.keep_checkpoints)
        return path

    def validate() -> dict[str, float]:
        net.eval()
        with torch.no_grad():
            figures = recipe.validate(net, data, model_cfg, stage)
        net.train()
        logbook.log(step, "val", figures)
        return figures

    try:
        net.train()
        batches = step_batches(data.train, train_cfg, procs.rank, local_batch, range(step, train_cfg.steps), workers)
        for batch in batches:
            batch = to_device(batch, procs.device)
            gen = torch.Generator(device="cpu").manual_seed(step_seed(train_cfg.seed, step, procs.rank))
            ctx = StepContext(step, procs.rank, procs.world_size, gen)
            lr = learning_rate(train_cfg, step)
            for group in optimizer.param_groups:
                group["lr"] = lr
            loss, figures = module(batch, ctx)
            if not torch.isfinite(loss):
                raise RuntimeError(f"loss is {float(loss)} at step {step}: training diverged (lower --set lr=...)")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if train_cfg.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(net.parameters(), train_cfg.grad_clip)
            optimizer.step()
            step += 1
            if step % train_cfg.log_every == 0 or step == train_cfg.steps:
                logged = {"loss": loss.detach(), **{k: v.detach() for k, v in figures.items()}}
                reduced = {
                    k: float(distributed.mean_over_processes(v.float().reshape(()), procs)) for k, v in logged.items()
                }
                logbook.log(step, "train", {**reduced, "lr": lr})
                progress.update(step, reduced["loss"])
            if procs.is_main and (step % train_cfg.val_every == 0 or step == train_cfg.steps):
                validation = validate()
                progress.note(step, validation)
            if procs.is_main and (step % train_cfg.checkpoint_every == 0 or step == train_cfg.steps):
                last_ckpt = checkpoint()
            distributed.barrier(procs)
    finally:
        progress.close()
        logbook.close()
    elapsed = time.monotonic() - started
    rate = (step - first_step) / elapsed if elapsed > 0 and step > first_step else 0.0
    return TrainResult(out, step, last_ckpt, validation, rate)


def _starting_point(recipe: Recipe, paths: Sequence[Path]) -> StartingPoint:
    """The weights of one run, or of several merged (a tensor two of them hold must agree)."""
    points = []
    for path in paths:
        ckpt = load_checkpoint(path)
        if ckpt.state.get("recipe") != recipe.name:
            raise UserError(f"--init {path}: holds a '{ckpt.state.get('recipe')}' run, not '{recipe.name}'")
        points.append(
            StartingPoint(ckpt.path, str(ckpt.state["stage"]), ckpt.step, ckpt.model_weights(), ckpt.data_spec())
        )
    first = points[0]
    weights = dict(first.weights)
    for other in points[1:]:
        for key, value in other.weights.items():
            if key in weights and (weights[key].shape != value.shape or not torch.equal(weights[key], value)):
                raise UserError(
                    f"--init {first.path} and {other.path}: both hold '{key}', with different values "
                    "(runs of other data or settings?)"
                )
            weights[key] = value
    if len(points) == 1:
        return first
    return StartingPoint(
        Path(",".join(str(p.path) for p in points)),
        "+".join(p.stage for p in points),
        max(p.step for p in points),
        weights,
        first.spec,
    )


def _init_record(start: StartingPoint | None, resume: Any) -> dict[str, Any] | None:
    """Where a run's first weights came from, kept in run.json and every checkpoint (resumed runs
    keep their first checkpoint's record)."""
    if start is not None:
        return {"path": str(start.path), "stage": start.stage, "step": start.step}
    return resume.state.get("init") if resume is not None else None


class _Progress:
    """A rich progress bar on a terminal; otherwise one line per validation on stderr."""

    def __init__(self, label: str, total: int, done: int, enabled: bool) -> None:
        self.enabled = enabled
        self.bar: Any = None
        if enabled and sys.stderr.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("loss {task.fields[loss]}"),
                TimeRemainingColumn(),
                transient=True,
            )
            self.task = self.bar.add_task(label, total=total, completed=done, loss="-")
            self.bar.start()
        self.total = total

    def update(self, step: int, loss: float) -> None:
        if self.bar is not None:
            self.bar.update(self.task, completed=step, loss=f"{loss:.4g}")

    def note(self, step: int, figures: dict[str, float]) -> None:
        if not self.enabled or not figures:
            return
        text = " ".join(f"{k} {v:.4g}" for k, v in figures.items())
        line = f"step {step}/{self.total}: val {text}"
        if self.bar is not None:
            self.bar.console.print(line)
        else:
            print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
