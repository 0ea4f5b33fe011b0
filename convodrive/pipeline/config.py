"""The run config (``--config``): a robot profile and/or ``generator:`` and ``backends:`` option sections."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import yaml

from convodrive.plumbing.errors import InputFileError


@dataclasses.dataclass
class RunConfig:
    """A ``--config`` YAML: a robot profile and/or ``generator:`` and ``backends:`` option sections."""

    path: Path | None = None
    data: dict[str, Any] = dataclasses.field(default_factory=dict)
    profile: Any = None  # convodrive.retargeting.RobotProfile when the file is a robot profile

    def generator_options(self, name: str) -> dict[str, Any]:
        return dict(_section(self.data, "generator", self.path).get(name) or {})

    def backend_options(self, name: str) -> dict[str, Any]:
        return dict(_section(self.data, "backends", self.path).get(name) or {})


def _section(data: dict[str, Any], key: str, path: Path | None) -> dict[str, Any]:
    value = data.get(key) or {}
    if not isinstance(value, dict):
        raise InputFileError(path or "config", f"'{key}' must be a mapping of names to options")
    return value


def load_run_config(path: str | os.PathLike[str] | None) -> RunConfig:
    if path is None:
        return RunConfig()
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such config file")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        raise InputFileError(path, f"not valid YAML{line}") from None
    if not isinstance(data, dict):
        raise InputFileError(path, "a config must be a YAML mapping")
    config = RunConfig(path=path, data=data)
    if "joints" in data:
        from convodrive.retargeting import load_profile

        config.profile = load_profile(path)
    return config
