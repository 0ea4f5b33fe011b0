"""Checkpoints as safetensors plus JSON: no pickles anywhere.

A checkpoint is a folder ``step-NNNNNNNN/`` holding ``model.safetensors`` (the weights),
``optimizer.safetensors`` (the optimizer's tensors, flattened to ``state.<param>.<name>``),
``data.npz`` (the data spec's arrays) and ``state.json`` (recipe, preset, stage, configs, data
spec info, step, the optimizer's non-tensor settings). It is written to a temporary folder and
renamed, so a checkpoint is complete or absent (a run removes the temporary folders of a save
that was killed). Everything ``convodrive export`` needs is inside. A damaged checkpoint is one
``InputFileError`` naming the file, never a traceback.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from convodrive.plumbing.errors import InputFileError, os_reason
from convodrive.training.recipe import DataSpec

CHECKPOINT_FORMAT = "convodrive-checkpoint"
CHECKPOINT_VERSION = 1
_PREFIX = "step-"
_TEMP_PREFIX = ".ckpt-"
_UNREADABLE = (OSError, SafetensorError, ValueError, KeyError, EOFError, zipfile.BadZipFile)
"""What reading a damaged safetensors or npz file raises."""


@dataclasses.dataclass
class Checkpoint:
    path: Path
    state: dict[str, Any]
    """``state.json``: format, recipe, preset, stage, model/train config, data info, step, ..."""

    @property
    def step(self) -> int:
        return int(self.state["step"])

    def model_weights(self) -> dict[str, torch.Tensor]:
        path = self.path / "model.safetensors"
        try:
            return load_file(str(path))
        except _UNREADABLE as exc:
            raise InputFileError(path, f"cannot be read ({_reason(exc)})") from None

    def data_spec(self) -> DataSpec:
        path = self.path / "data.npz"
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except _UNREADABLE as exc:
            raise InputFileError(path, f"cannot be read ({_reason(exc)})") from None
        return DataSpec(info=self.state["data"], arrays=arrays)

    def optimizer_state(self) -> dict[str, Any]:
        path = self.path / "optimizer.safetensors"
        state: dict[int, dict[str, torch.Tensor]] = {}
        try:
            for key, value in load_file(str(path)).items():
                _, index, name = key.split(".", 2)
                state.setdefault(int(index), {})[name] = value
        except _UNREADABLE as exc:
            raise InputFileError(path, f"cannot be read ({_reason(exc)})") from None
        return {"state": state, "param_groups": self.state["optimizer"]["param_groups"]}


def _reason(exc: BaseException) -> str:
    text = os_reason(exc) if isinstance(exc, OSError) else " ".join(str(exc).split()) or type(exc).__name__
    return text[:160]


def save_checkpoint(
    folder: Path, model: torch.nn.Module, optimizer: torch.optim.Optimizer, spec: DataSpec, state: dict[str, Any]
) -> Path:
    """Write ``folder/step-NNNNNNNN`` atomically and return it. A write that fails (a full disk) is
    one ``InputFileError``; the checkpoints before stay as they were."""
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"{_PREFIX}{int(state['step']):08d}"
    tmp = Path(tempfile.mkdtemp(prefix=_TEMP_PREFIX, dir=folder))
    try:
        _write(tmp, model, optimizer, spec, state)
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    except (OSError, SafetensorError) as exc:
        before = list_checkpoints(folder)
        kept = f"the last checkpoint, {before[-1].name}, is intact" if before else "no checkpoint was written"
        raise InputFileError(final, f"cannot be written ({_reason(exc)}); {kept}") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return final


def _write(
    tmp: Path, model: torch.nn.Module, optimizer: torch.optim.Optimizer, spec: DataSpec, state: dict[str, Any]
) -> None:
    weights = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    save_file(weights, str(tmp / "model.safetensors"))
    opt = optimizer.state_dict()
    flat = {
        f"state.{index}.{name}": (value if torch.is_tensor(value) else torch.tensor(value)).detach().cpu().contiguous()
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


def remove_stale_temps(folder: Path) -> None:
    """Remove the temporary folders of saves that never finished (a process killed mid-save)."""
    if folder.is_dir():
        for tmp in folder.glob(f"{_TEMP_PREFIX}*"):
            shutil.rmtree(tmp, ignore_errors=True)


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
    except OSError as exc:
        raise InputFileError(state_path, f"cannot be read ({os_reason(exc)})") from None
    _check_state(state_path, state)
    for name in ("model.safetensors", "optimizer.safetensors", "data.npz"):
        if not (path / name).is_file():
            raise InputFileError(path / name, "missing from the checkpoint")
    return Checkpoint(path, state)


_STATE_TYPES: dict[str, type | tuple[type, ...]] = {
    "recipe": str,
    "preset": str,
    "stage": str,
    "model_config": dict,
    "train_config": dict,
    "data": dict,
    "optimizer": dict,
}


def _check_state(state_path: Path, state: Any) -> None:
    """``state.json`` holds what a resumed run and an export read, of the types they read."""
    if not isinstance(state, dict):
        raise InputFileError(state_path, f"is not a JSON object (a {type(state).__name__})")
    if state.get("format") != CHECKPOINT_FORMAT:
        raise InputFileError(state_path, "is not a convodrive checkpoint")
    if state.get("version") != CHECKPOINT_VERSION:
        raise InputFileError(
            state_path, f"has checkpoint version {state.get('version')}, expected {CHECKPOINT_VERSION}"
        )
    step = state.get("step")
    if not isinstance(step, int) or isinstance(step, bool) or step < 0:
        raise InputFileError(state_path, f"'step' is {step!r}, not a step count")
    for key, kind in _STATE_TYPES.items():
        if not isinstance(state.get(key), kind):
            raise InputFileError(state_path, f"'{key}' is {state.get(key)!r:.60}, not a JSON {kind.__name__}")  # type: ignore[union-attr]
    if not isinstance(state["optimizer"].get("param_groups"), list):
        raise InputFileError(state_path, "'optimizer' holds no 'param_groups' list")


def load_weights(model: torch.nn.Module, checkpoint: Checkpoint) -> None:
    path = checkpoint.path / "model.safetensors"
    try:
        missing, unexpected = model.load_state_dict(checkpoint.model_weights(), strict=False)
    except RuntimeError as exc:  # a tensor of another shape than the model config builds
        first = next((line.strip() for line in str(exc).splitlines()[1:] if line.strip()), str(exc))
        raise InputFileError(path, f"does not fit the network of state.json's model_config ({first[:200]})") from None
    if missing or unexpected:
        raise InputFileError(
            path, f"does not fit the network (missing {list(missing)[:3]}, unexpected {list(unexpected)[:3]})"
        )


def load_optimizer(optimizer: torch.optim.Optimizer, checkpoint: Checkpoint) -> None:
    """The optimizer's state of a resumed run; a file of another network is one ``InputFileError``."""
    try:
        optimizer.load_state_dict(checkpoint.optimizer_state())
    except (ValueError, KeyError, TypeError, RuntimeError) as exc:
        raise InputFileError(
            checkpoint.path / "optimizer.safetensors", f"does not fit the network ({_reason(exc)})"
        ) from None
