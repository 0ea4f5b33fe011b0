"""The run config (``--config``): a robot profile and/or ``generator:`` and ``backends:`` option sections.

``--config`` follows the one rule for profile names (``retargeting.profile.resolve_profile_path``):
a file that exists, else the name of a bundled profile. Each section names plugins; every name must
be a plugin this installation knows, and the options of each are checked against its declaration,
so a typo in a section is one line naming the file, even for a plugin the run does not use.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from convodrive.plugins import BACKEND_GROUP, GENERATOR_GROUP, load_plugin, plugin_kind, plugin_names, unknown_plugin
from convodrive.plugins.options import check_options
from convodrive.plumbing.errors import InputFileError, UserError
from convodrive.plumbing.safe_yaml import load_yaml_file
from convodrive.plumbing.text import clip_value

SECTIONS = {"generator": GENERATOR_GROUP, "backends": BACKEND_GROUP}


@dataclasses.dataclass
class RunConfig:
    """A ``--config`` YAML: a robot profile and/or ``generator:`` and ``backends:`` option sections."""

    path: Path | None = None
    data: dict[str, Any] = dataclasses.field(default_factory=dict)
    profile: Any = None  # convodrive.retargeting.RobotProfile when the file is a robot profile

    @property
    def where(self) -> str:
        """The file, for messages ('' when there is none)."""
        return str(self.path) if self.path else ""

    def generator_options(self, name: str) -> Mapping[str, Any] | None:
        return section(self.data, "generator", self.where).get(name)

    def backend_options(self, name: str) -> Mapping[str, Any] | None:
        return section(self.data, "backends", self.where).get(name)


def section(data: Mapping[str, Any], key: str, where: str) -> dict[str, Any]:
    """The ``generator:`` or ``backends:`` section of a config or profile, as given."""
    value = data.get(key) or {}
    if not isinstance(value, dict):
        raise InputFileError(
            where or "config", f"'{key}' must be a mapping of names to options, got {clip_value(value)}"
        )
    return value


def check_sections(data: Mapping[str, Any], where: str) -> None:
    """Every plugin a config names exists, and its options match its declaration (plugins whose
    extra is not installed excepted: their declaration cannot be read here)."""
    for key, group in SECTIONS.items():
        for name, raw in section(data, key, where).items():
            if name not in plugin_names(group):
                raise InputFileError(where or "config", f"{key}: {unknown_plugin(group, name)}")
            try:
                cls: Any = load_plugin(group, name)
            except UserError:
                continue
            check_options(cls.Options, raw, plugin=f"{plugin_kind(group)} {name}", where=where)


def load_run_config(path_or_name: str | os.PathLike[str] | None) -> RunConfig:
    if path_or_name is None:
        return RunConfig()
    from convodrive.retargeting.profile import RobotProfile, missing_profile, resolve_profile_path

    path = resolve_profile_path(path_or_name)
    if not path.exists():
        raise missing_profile(path_or_name, path, "config")
    data = load_yaml_file(path)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise InputFileError(path, f"a config must be a YAML mapping, got {clip_value(data)}")
    config = RunConfig(path=path, data=data)
    if "joints" in data:
        config.profile = RobotProfile.from_dict(data, path)
    check_sections(data, config.where)
    return config
