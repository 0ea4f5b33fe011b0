"""Checkpoints as safetensors plus JSON: no pickles anywhere.

A checkpoint is a folder ``step-NNNNNNNN/`` holding ``model.safetensors`` (the weights),
``optimizer.safetensors`` (the optimizer's tensors, flattened to ``state.<param>.<name>``),
``data.npz`` (the data spec's arrays) and ``state.json`` (recipe, preset, stage, configs, data
spec info, step, the optimizer's non-tensor settings). It is written to a temporary folder and
renamed, so a checkpoint is complete or absent. Everything ``convodrive export`` needs is inside.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from convodrive.plumbing.errors import InputFileError
from convodrive.training.recipe import DataSpec

CHECKPOINT_FORMAT = "convodrive-checkpoint"
CHECKPOINT_VERSION = 1
_PREFIX = "step-"


@dataclasses.dataclass
class Checkpoint:
    path: Path
    state: dict[str, Any]
    """``state.json``: format, recipe, preset, stage, model/train config, data info, step, ..."""

    @property
    def step(self) -> int:
        return int(self.state["step"])

    def model_weights(self) -> dict[str, torch.Tensor]:
        return load_file(str(self.path / "model.safetensors"))

    def data_spec(self) -> DataSpec:
        with np.load(self.path / "data.npz", allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        return DataSpec(info=self.state["data"], arrays=arrays)

    def optimizer_state(self) -> dict[str, Any]:
        tensors = load_file(str(self.path / "optimizer.safetensors"))
        state: dict[int, dict[str, torch.Tensor]] = {}
        for key, value in tensors.items():
            _, index, name = key.split(".", 2)
            state.setdefault(int(index), {})[name] = value
        return {"state": state, "param_groups": self.state["optimizer"]["param_groups"]}


def save_checkpoint(
    folder: Path, model: torch.nn.Module, optimizer: torch.optim.Optimizer, spec: DataSpec, state: dict[str, Any]
) -> Path:
    """Write ``folder/step-NNNNNNNN`` atomically and return it."""
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"{_PREFIX}{int(state['step']):08d}"
    tmp = Path(tempfile.mkdtemp(prefix=".ckpt-", dir=folder))
    try:
        weights = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
        save_file(weights, str(tmp / "model.safetensors"))
        opt = optimizer.state_dict()
        flat = {
            f"state.{index}.{name}": (value if torch.is_tensor(value) else torch.tensor(value))
            .detach()
            .cpu()
            .contiguous()
            for index, entries in opt["state"].items()
            for name, value in entries.items()
        }
        save_file(flat, str(tmp / "optimizer.safetensors"))
        np.savez(tmp / "data.npz", **spec.arrays)
        full_state = {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            **state,
            "data": spec.info,
            "optimizer": {"param_groups": opt["param_groups"]},
        }
        (tmp / "state.json").write_text(json.dumps(full_state, indent=2, sort_keys=True), encoding="utf-8")
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return final


def list_checkpoints(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.name.startswith(_PREFIX) and (p / "state.json").is_file())


def prune_checkpoints(folder: Path, keep: int) -> None:
    for old in list_checkpoints(folder)[:-keep] if keep > 0 else []:
        shutil.rmtree(old, ignore_errors=True)


def load_checkpoint(path: str | Path) -> Checkpoint:
    """A checkpoint folder, or a run folder (its latest checkpoint). ``InputFileError`` names what is wrong."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, "no such checkpoint or run folder")
    if not (path / "state.json").is_file():
        found = list_checkpoints(path / "checkpoints") or list_checkpoints(path)
        if not found:
            raise InputFileError(path, "holds no checkpoint (expected state.json, or checkpoints/step-*/)")
        path = found[-1]
    state_path = path / "state.json"
    try:
        state = json.loads(state_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(state_path, f"is not valid JSON ({exc})") from None
    if state.get("format") != CHECKPOINT_FORMAT:
        raise InputFileError(state_path, "is not a convodrive checkpoint")
    if state.get("version") != CHECKPOINT_VERSION:
        raise InputFileError(
            state_path, f"has checkpoint version {state.get('version')}, expected {CHECKPOINT_VERSION}"
        )
    for name in ("model.safetensors", "optimizer.safetensors", "data.npz"):
        if not (path / name).is_file():
            raise InputFileError(path / name, "missing from the checkpoint")
    return Checkpoint(path, state)


def load_weights(model: torch.nn.Module, checkpoint: Checkpoint) -> None:
    try:
        weights = checkpoint.model_weights()
    except Exception as exc:  # safetensors raises its own error types for a damaged file
        raise InputFileError(checkpoint.path / "model.safetensors", f"cannot be read ({exc})") from None
    missing, unexpected = model.load_state_dict(weights, strict=False)
    if missing or unexpected:
        raise InputFileError(
            checkpoint.path / "model.safetensors",
            f"does not fit the network (missing {list(missing)[:3]}, unexpected {list(unexpected)[:3]})",
        )
