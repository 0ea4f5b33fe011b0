"""Model folders: what ``convodrive export`` writes and every learned generator reads.

A model folder holds ONNX graphs, NumPy arrays (normalisation statistics, codebooks) and a
``model.json`` that describes them: the model and preset, its architecture, the feature spec,
the training corpus, and the sha256 of every file it names. Loading verifies each hash, so a
missing, truncated or swapped file is one line naming it, never a confusing ONNX Runtime error
halfway through a run. The structure of ``model.json`` is checked as well (a hash proves a file
is the one described, not that the description is sound): the tables are objects, every graph
names a hashed file, a missing architecture entry or a graph whose inputs are not the ones
described is one line naming the folder or file, never a traceback.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import zipfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.plumbing.errors import InputFileError

MODEL_FORMAT = "convodrive-model"
MODEL_FORMAT_VERSION = 1
MODEL_JSON = "model.json"


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


class Architecture(dict[str, Any]):
    """``model.json``'s ``architecture``: a key it lacks is an ``InputFileError`` naming the file."""

    def __init__(self, source: Path, entries: dict[str, Any]) -> None:
        super().__init__(entries)
        self.source = source

    def __missing__(self, key: str) -> Any:
        raise InputFileError(self.source, f"architecture has no '{key}' (the file was edited or is not this model's)")


@dataclasses.dataclass(frozen=True)
class ModelFolder:
    """A verified model folder. ``spec`` is the parsed ``model.json``."""

    path: Path
    spec: dict[str, Any]

    @property
    def model(self) -> str:
        return str(self.spec["model"])

    @property
    def graphs(self) -> dict[str, dict[str, Any]]:
        return dict(self.spec.get("graphs", {}))

    def graph_path(self, name: str) -> Path:
        """The ONNX file of graph ``name`` (its hash was checked when the folder loaded)."""
        graphs = self.graphs
        if name not in graphs:
            raise InputFileError(
                self.path / MODEL_JSON, f"has no graph '{name}' (it has: {', '.join(graphs) or 'none'})"
            )
        return self.path / graphs[name]["file"]

    def require_graphs(self, names: Iterable[str], hint: str) -> None:
        """An ``InputFileError`` naming the folder when it lacks any of ``names``: an export of an
        earlier training stage; ``hint`` says which stage to export."""
        missing = [g for g in names if g not in self.graphs]
        if missing:
            raise InputFileError(
                self.path, f"holds a '{self.spec.get('stage')}' stage export without {', '.join(missing)}: {hint}"
            )

    def check_graph(self, name: str, inputs: Sequence[str], outputs: Sequence[str]) -> None:
        """An ``InputFileError`` naming the file when graph ``name``'s inputs or outputs are not the
        ones ``model.json`` describes (graph files swapped and their hashes recomputed)."""
        entry = self.graphs[name]
        for what, found in (("inputs", list(inputs)), ("outputs", list(outputs))):
            if what in entry and list(entry[what]) != found:
                raise InputFileError(
                    self.path / entry["file"],
                    f"is not graph '{name}': its {what} are {', '.join(found)}, model.json describes {', '.join(entry[what])}",
                )

    def arrays(self, name: str) -> dict[str, np.ndarray]:
        """The arrays of the ``.npz`` file ``name`` (e.g. ``normalisation.npz``), loaded without pickles."""
        if name not in self.spec["files"]:
            raise InputFileError(self.path / MODEL_JSON, f"names no file '{name}'")
        try:
            with np.load(self.path / name, allow_pickle=False) as data:
                return {key: data[key] for key in data.files}
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
            raise InputFileError(self.path / name, f"is not a readable .npz ({exc.__class__.__name__})") from None


def load_model_folder(path: str | Path) -> ModelFolder:
    """Read ``model.json`` and verify every file it names. ``InputFileError`` names the bad file."""
    folder = Path(path)
    if not folder.is_dir():
        raise InputFileError(folder, "no such model folder" if not folder.exists() else "is not a folder")
    meta_path = folder / MODEL_JSON
    if not meta_path.is_file():
        raise InputFileError(meta_path, "missing: not a convodrive model folder (make one with `convodrive export`)")
    try:
        spec = json.loads(meta_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(meta_path, f"is not valid JSON ({exc})") from None
    if not isinstance(spec, dict) or spec.get("format") != MODEL_FORMAT:
        raise InputFileError(meta_path, f"is not a {MODEL_FORMAT} description")
    version = spec.get("version")
    if version != MODEL_FORMAT_VERSION:
        raise InputFileError(meta_path, f"has format version {version}; this convodrive reads {MODEL_FORMAT_VERSION}")
    files = spec.get("files")
    if not isinstance(files, dict) or not files or "model" not in spec:
        raise InputFileError(meta_path, "lists no files or names no model")
    for name, expected in files.items():
        file = folder / name
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise InputFileError(meta_path, f"names a file outside the folder: {name}")
        if not file.is_file():
            raise InputFileError(file, "missing from the model folder")
        if sha256_file(file) != expected:
            raise InputFileError(file, "does not match the sha256 in model.json (truncated, changed or replaced)")
    _check_structure(meta_path, spec)
    spec["architecture"] = Architecture(meta_path, spec.get("architecture", {}))
    return ModelFolder(folder, spec)


def _check_structure(meta_path: Path, spec: dict[str, Any]) -> None:
    """The tables a generator reads are objects, and every graph names a hashed file."""
    if not isinstance(spec["model"], str):
        raise InputFileError(meta_path, "'model' must be a name")
    for key in ("graphs", "architecture", "features"):
        if not isinstance(spec.get(key, {}), dict):
            raise InputFileError(meta_path, f"'{key}' must be an object, not {type(spec[key]).__name__}")
    for name, graph in spec.get("graphs", {}).items():
        if not isinstance(graph, dict) or not isinstance(graph.get("file"), str):
            raise InputFileError(meta_path, f"graph '{name}' must be an object naming its file")
        if graph["file"] not in spec["files"]:
            raise InputFileError(meta_path, f"graph '{name}' names a file that has no sha256")
        for what in ("inputs", "outputs"):
            if what in graph and not (isinstance(graph[what], list) and all(isinstance(n, str) for n in graph[what])):
                raise InputFileError(meta_path, f"graph '{name}' {what} must be a list of names")
