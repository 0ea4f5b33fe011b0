"""Training settings shared by every recipe, and presets as plain overrides."""

from __future__ import annotations

import dataclasses
import difflib
from typing import Any, TypeVar

from convodrive.plumbing.errors import UserError

C = TypeVar("C")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How to train, whatever the model. ``batch_size`` is global: DDP splits it across processes."""

    steps: int = 2000
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 0.0
    warmup_steps: int = 100
    decay_steps: int = 0
    """Cosine decay to a tenth of ``lr`` over this many steps after warm-up, then flat; 0: no decay.
    Not tied to ``steps``, so a run extended with a larger ``--steps`` continues exactly."""
    grad_clip: float = 1.0
    seed: int = 0
    log_every: int = 20
    val_every: int = 500
    checkpoint_every: int = 500
    keep_checkpoints: int = 2


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named set of overrides of a recipe's model config and of ``TrainConfig``."""

    description: str
    model: dict[str, Any] = dataclasses.field(default_factory=dict)
    train: dict[str, Any] = dataclasses.field(default_factory=dict)


def with_overrides(config: C, overrides: dict[str, Any], what: str) -> C:
    """``config`` with ``overrides`` applied; an unknown key or a wrong type is one ``UserError`` line."""
    fields = {f.name: f for f in dataclasses.fields(config)}  # type: ignore[arg-type]
    values = {}
    for key, value in overrides.items():
        if key not in fields:
            close = difflib.get_close_matches(key, fields, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise UserError(f"{what}: unknown setting '{key}'{hint}")
        current = getattr(config, key)
        if isinstance(current, bool) or current is None:
            values[key] = value
        elif isinstance(current, int) and isinstance(value, int) and not isinstance(value, bool):
            values[key] = value
        elif isinstance(current, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
            values[key] = float(value)
        elif isinstance(current, (str, tuple, list)) and isinstance(value, type(current)):
            values[key] = value
        elif isinstance(current, tuple) and isinstance(value, list):
            values[key] = tuple(value)
        else:
            raise UserError(f"{what}: setting '{key}' expects {type(current).__name__}, got {value!r}")
    return dataclasses.replace(config, **values)  # type: ignore[type-var]


def to_dict(config: Any) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(config).items()}
