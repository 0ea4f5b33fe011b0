"""Backends of a run: made with their merged options, opened, each paired with its retargeter.

Which joint space a backend gets: a backend with no ``default_profile`` (render, record) takes
canonical motion only. A robot backend uses the run config's profile when the config is one (it
has ``joints``), else its own default profile from config/robots. Its options merge, lowest first:
its profile's ``backends.<name>``, the run config's ``backends.<name>``, then the caller's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from convodrive.backends.base import Backend, Session
from convodrive.motion.targets import TargetSpec
from convodrive.pipeline.config import RunConfig
from convodrive.plugins import BACKEND_GROUP, load_plugin
from convodrive.plumbing.errors import UserError
from convodrive.scheduler import Route


@dataclasses.dataclass
class PlannedBackend:
    """A backend made with its options, not yet opened, and the profile that drives it."""

    name: str
    backend: Backend
    profile: Any  # RobotProfile or None


def make_backends(
    names: Iterable[str], config: RunConfig, options_by_backend: dict[str, dict[str, Any]]
) -> list[PlannedBackend]:
    """Instantiate each named backend with its merged options (a bad name or option is a UserError).

    Instances, not classes, say whether they are real-time: the renderer becomes one when its
    live window can open."""
    planned = []
    for name in dict.fromkeys(names):
        cls: type[Backend] = load_plugin(BACKEND_GROUP, name)
        profile = _profile_for(cls, config)
        options: dict[str, Any] = {}
        if profile is not None:
            if profile.model_path is not None:
                options["model"] = str(profile.model_path)  # the body a simulator loads
            options.update(profile.backend_options(name))
        options.update(config.backend_options(name))
        options.update(options_by_backend.get(name, {}))
        planned.append(PlannedBackend(name, cls(options), profile))
    return planned


def open_backends(planned: list[PlannedBackend], session: Session) -> tuple[list[Route], dict[str, str]]:
    """Open each backend. A user mistake aborts the run (closing what opened); any other fault at
    open fails that backend alone, and the run goes on without it."""
    routes: list[Route] = []
    failed: dict[str, str] = {}
    retargeters: dict[str, Any] = {}
    try:
        for item in planned:
            profile = item.profile
            spec = profile.spec if profile is not None else TargetSpec.empty()
            try:
                item.backend.open(spec, session)
            except UserError:
                raise
            except Exception as exc:  # hardware or driver fault: this backend only
                failed[item.name] = f"{exc.__class__.__name__}: {exc}"
                continue
            retarget = None
            key = ""
            if profile is not None:
                key = str(profile.path)
                if key not in retargeters:
                    from convodrive.retargeting import Retargeter

                    retargeters[key] = Retargeter(profile)
                retarget = retargeters[key]
            routes.append(Route(item.backend, retarget, key))
    except BaseException:
        close_all(routes)
        raise
    return routes, failed


def close_all(routes: list[Route]) -> None:
    for route in routes:
        try:
            route.backend.close()
        except Exception:
            pass


def _profile_for(cls: type[Backend], config: RunConfig) -> Any:
    if cls.default_profile is None:
        return None
    override = config.backend_options(cls.name).get("profile") if config.path else None
    from convodrive.retargeting import load_profile

    if override:
        return load_profile(override)
    if config.profile is not None:
        return config.profile
    return load_profile(cls.default_profile)


def safe_outputs(backend: Backend) -> list[Path]:
    try:
        return list(backend.outputs())
    except Exception:
        return []
