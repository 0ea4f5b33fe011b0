"""Where a new run's first weights come from (``--init``): one run's, or several runs' merged."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from convodrive.plumbing.errors import UserError
from convodrive.training.checkpoint import Checkpoint, load_checkpoint
from convodrive.training.recipe import Recipe, StartingPoint


def starting_point(recipe: Recipe, paths: Sequence[Path]) -> StartingPoint:
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


def init_record(start: StartingPoint | None, resume: Checkpoint | None) -> dict[str, Any] | None:
    """Where a run's first weights came from, kept in run.json and every checkpoint (resumed runs
    keep their first checkpoint's record)."""
    if start is not None:
        return {"path": str(start.path), "stage": start.stage, "step": start.step}
    return resume.state.get("init") if resume is not None else None
