"""Robot profiles: the YAML that says how canonical motion drives one body (DESIGN, "Retargeting").

A profile names the body's joints and, per joint, where its value comes from (a canonical joint's
rotation split onto a hinge axis, a blendshape through a piecewise-linear map, or a weighted sum of
those), then gain, offset, direction, limits and smoothing. A new robot is a new YAML file.
Everything is validated here, once, so that a mistake is one line naming the file and the key
rather than a traceback in the middle of a run. The run config may add top-level ``backends`` and
``generator`` sections; they are opaque here and handed out by name.

The schema and the parsed objects are ``profile_schema``; the checks that give those one-line
errors are ``profile_checks``.
"""

from __future__ import annotations

import importlib.resources
import os
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.motion.targets import TargetSpec
from convodrive.plumbing.errors import InputFileError, UserError
from convodrive.plumbing.safe_yaml import load_yaml_file
from convodrive.plumbing.text import clip_value
from convodrive.retargeting.profile_checks import Checker, parse_ik, parse_joint, parse_smoothing, resolve_model
from convodrive.retargeting.profile_schema import (
    OPAQUE_KEYS,
    SMOOTHING_DEFAULT,
    TOP_KEYS,
    IKConfig,
    JointMap,
    Smoothing,
)


class RobotProfile:
    """A validated robot profile. ``spec`` is what backends are opened with."""

    def __init__(
        self,
        name: str,
        joints: tuple[JointMap, ...],
        model_path: Path | None,
        ik: IKConfig | None,
        path: Path | None,
        extras: dict[str, Any],
        description: str = "",
    ) -> None:
        self.name = name
        self.description = description
        self.joints = joints
        self.model_path = model_path
        self.ik = ik
        self.path = path
        self._extras = extras
        self.spec = TargetSpec(
            name=name,
            names=tuple(j.name for j in joints),
            lower=np.array([j.lower for j in joints]),
            upper=np.array([j.upper for j in joints]),
            neutral=np.array([j.neutral for j in joints]),
            max_velocity=np.array([j.max_velocity for j in joints]),
            max_acceleration=np.array([j.max_acceleration for j in joints]),
            units=tuple(j.units for j in joints),  # type: ignore[arg-type]
            model=model_path,
        )

    def __repr__(self) -> str:
        return f"RobotProfile({self.name!r}, {len(self.joints)} joints, model={self.model_path})"

    def _section(self, key: str, name: str) -> dict[str, Any]:
        section = self._extras.get(key) or {}
        options = section.get(name) if isinstance(section, dict) else None
        if options is None:
            return {}
        if not isinstance(options, dict):
            raise InputFileError(self.path or self.name, f"{key}.{name}: must be a mapping of options")
        return dict(options)

    @property
    def sections(self) -> dict[str, Any]:
        """The profile's ``backends:`` and ``generator:`` sections, as given."""
        return dict(self._extras)

    def backend_options(self, name: str) -> dict[str, Any]:
        """Options for backend ``name`` from the top-level ``backends:`` section (opaque here)."""
        return self._section("backends", name)

    def generator_options(self, name: str) -> dict[str, Any]:
        """Options for generator ``name`` from the top-level ``generator:`` section (opaque here)."""
        return self._section("generator", name)

    @classmethod
    def from_dict(cls, data: Any, source: str | Path = "<profile>") -> RobotProfile:
        ck = Checker(str(source))
        data = ck.mapping(data, "")
        ck.keys(data, TOP_KEYS, "")
        path = (
            Path(source)
            if isinstance(source, Path) or (isinstance(source, str) and source.endswith((".yaml", ".yml")))
            else None
        )
        name = ck.string(data.get("name", path.stem if path else None), "name")
        defaults = ck.mapping(data.get("defaults", {}), "defaults")
        ck.keys(defaults, ("smoothing",), "defaults")
        smoothing = Smoothing(**SMOOTHING_DEFAULT)
        if "smoothing" in defaults:
            smoothing = parse_smoothing(ck, defaults["smoothing"], "defaults.smoothing", smoothing)
        raw_joints = ck.mapping(data.get("joints"), "joints")
        if not raw_joints:
            ck.fail("joints", "names no joint")
        ik_raw = data.get("ik")
        ik_names = (
            set(ik_raw.get("joints") or [])
            if isinstance(ik_raw, dict) and isinstance(ik_raw.get("joints"), list)
            else set()
        )
        joints = {str(n): parse_joint(ck, str(n), v, smoothing, str(n) in ik_names) for n, v in raw_joints.items()}
        ik = parse_ik(ck, data["ik"], joints) if data.get("ik") is not None else None
        model_path = resolve_model(ck, data.get("model"), path.parent if path else None)
        if ik is not None and model_path is None:
            ck.fail("ik", "needs a model: (the MJCF that IK runs on)")
        for key in OPAQUE_KEYS:
            if key in data and data[key] is not None:
                ck.mapping(data[key], key)
        extras = {k: data[k] for k in OPAQUE_KEYS if data.get(k) is not None}
        description = data.get("description", "")
        if not isinstance(description, str):
            ck.fail("description", f"must be text, got {clip_value(description)}")
        return cls(name, tuple(joints.values()), model_path, ik, path, extras, description)


def bundled_profiles() -> list[str]:
    """Names of the profiles shipped in convodrive.config/robots."""
    return sorted(p.stem for p in _bundled_dir().glob("*.yaml"))


def _bundled_dir() -> Path:
    return Path(str(importlib.resources.files("convodrive.config").joinpath("robots")))


def resolve_profile_path(path_or_name: str | os.PathLike[str]) -> Path:
    """The one rule for naming a profile or run config, everywhere (``--config``, a run config's
    ``profile:``, the servo tools): a file that exists is that file; else a bare name (no folder,
    no .yaml) is the bundled profile of that name; anything else is a path that does not exist."""
    text = str(path_or_name)
    candidate = Path(text).expanduser()
    if candidate.exists() or "/" in text or os.sep in text or candidate.suffix.lower() in (".yaml", ".yml"):
        return candidate
    return _bundled_dir() / f"{text}.yaml"


def missing_profile(path_or_name: str | os.PathLike[str], path: Path, what: str = "robot profile") -> UserError:
    """One line for a profile or config that is not there, listing the bundled names."""
    names = ", ".join(bundled_profiles())
    if path.parent == _bundled_dir():
        return UserError(
            f"unknown robot profile {clip_value(str(path_or_name))} (no such {what} file, nor a bundled profile: {names})"
        )
    return InputFileError(path, f"no such {what} file (or give a bundled profile by name: {names})")


def load_profile(path_or_name: str | os.PathLike[str]) -> RobotProfile:
    """Load and validate a robot profile; raise ``InputFileError`` naming the file and key."""
    path = resolve_profile_path(path_or_name)
    if not path.exists():
        raise missing_profile(path_or_name, path)
    return RobotProfile.from_dict(load_yaml_file(path), path)
