"""Training settings shared by every recipe, and presets as plain overrides."""

from __future__ import annotations

import dataclasses
import difflib
import math
from typing import Any, TypeVar

from convodrive.audio.augment import Augment, parse_kinds
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
    augment: str = ""
    """Audio augmentation of training windows (``audio.augment``): ``all`` or a comma list of
    speed, pitch, reverb, bleed, level, telephone, noise; empty (the default): none."""
    augment_p: float = 0.5
    """The chance each named kind applies to a window."""

    def check(self) -> None:
        """Refuse settings no run can use, before anything runs: one ``UserError`` naming the option."""
        for name, high in (("steps", MAX_COUNT), ("batch_size", MAX_BATCH)):
            value = getattr(self, name)
            if not 1 <= value <= high:
                raise UserError(f"--{name.replace('_', '-')} must be between 1 and {high}, got {value}")
        if not (math.isfinite(self.lr) and 0 < self.lr <= MAX_LR):
            raise UserError(f"--set lr={self.lr}: the learning rate must be a number above 0 and at most {MAX_LR:g}")
        for name in ("weight_decay", "grad_clip"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise UserError(f"--set {name}={value}: must be a finite number, 0 or more")
        for name, low in (("log_every", 1), ("val_every", 1), ("checkpoint_every", 1), ("warmup_steps", 0)):
            value = getattr(self, name)
            if not low <= value <= MAX_COUNT:
                raise UserError(f"--set {name}={value}: must be between {low} and {MAX_COUNT}")
        try:
            parse_kinds(self.augment)
        except ValueError as exc:
            raise UserError(f"--set augment={self.augment}: {exc}") from None
        if not (math.isfinite(self.augment_p) and 0 <= self.augment_p <= 1):
            raise UserError(f"--set augment_p={self.augment_p}: must be between 0 and 1")
        for name in ("decay_steps", "keep_checkpoints", "seed"):
            value = getattr(self, name)
            if not 0 <= value <= MAX_COUNT:
                raise UserError(f"--set {name}={value}: must be between 0 and {MAX_COUNT}")


def augmentation(config: TrainConfig) -> Augment | None:
    """The run's audio augmentation, None when it has none."""
    kinds = parse_kinds(config.augment)
    return Augment(kinds, config.augment_p) if kinds else None


MAX_COUNT = 10**9
"""The largest step count, interval, batch size or seed a setting may name."""
MAX_BATCH = 1 << 16
"""The largest global batch: 500 times the largest preset's (the loop also checks one batch fits in memory)."""
MAX_LR = 1.0
"""No optimiser step of AdamW this large converges: 1e30 or infinity only diverge at the first step."""


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
