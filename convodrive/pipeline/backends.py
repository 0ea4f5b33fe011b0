"""Backends of a run: made with their merged options, opened, each paired with its retargeter.

Which joint space a backend gets: a backend with no ``default_profile`` (render, record) takes
canonical motion only. A robot backend drives the profile its ``profile`` option names (from the
run config or ``-B``), else the run config when that is a profile, else its own default profile.
Its options merge, lowest first: its profile's ``backends.<name>``, the run config's
``backends.<name>``, then the caller's (``-B``); each layer is checked against the backend's
declared options and a mistake names the file it came from. Which layer set each option is kept, so
a mistake the backend finds only at open (a joint its profile lacks) names that file too.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from convodrive.backends.base import Backend, Session
from convodrive.motion.targets import TargetSpec
from convodrive.pipeline.config import RunConfig, check_sections
from convodrive.plugins import BACKEND_GROUP, load_plugin
from convodrive.plugins.options import check_options, merge_options
from convodrive.plumbing.errors import InputFileError, UserError, error_line
from convodrive.scheduler import Route

log = logging.getLogger(__name__)


@dataclasses.dataclass
class PlannedBackend:
    """A backend made with its options, not yet opened, and the profile that drives it."""

    name: str
    backend: Backend
    profile: Any  # RobotProfile or None
    sources: dict[str, str] = dataclasses.field(default_factory=dict)
    """Option name to the file whose layer set it ("" for the command line's ``-B``)."""

    def where(self, error: UserError) -> UserError:
        """``error`` from opening this backend, led by the file that set the option it names
        (``backends.<name>.<option>...``); as it was when the option came from ``-B`` or a default."""
        message = str(error)
        found = re.match(rf"backends\.{re.escape(self.name)}\.(\w+)", message)
        source = self.sources.get(found.group(1), "") if found else ""
        if not source or message.startswith(source):
            return error
        return InputFileError(source, message)


def make_backends(
    names: Iterable[str], config: RunConfig, options_by_backend: Mapping[str, Mapping[str, Any]]
) -> list[PlannedBackend]:
    """Instantiate each named backend with its merged options (a bad name or option is a UserError).

    Instances, not classes, say whether they are real-time: the renderer becomes one when its
    live window can open."""
    names = list(dict.fromkeys(names))
    stray = [n for n in options_by_backend if n not in names]
    if stray:
        raise UserError(f"-B {stray[0]}.…: backend '{stray[0]}' is not in this run (its backends: {', '.join(names)})")
    planned = []
    for name in names:
        cls: type[Backend] = load_plugin(BACKEND_GROUP, name)
        plugin = f"backend {name}"
        config_layer = config.backend_options(name)
        cli_layer = options_by_backend.get(name)
        chosen = {
            **check_options(cls.Options, config_layer, plugin=plugin, where=config.where),
            **check_options(cls.Options, cli_layer, plugin=plugin),
        }.get("profile")
        profile = _profile_for(cls, config, chosen)
        layers: list[tuple[str, Mapping[str, Any] | None]] = []
        if profile is not None and profile is not config.profile:
            check_sections(profile.sections, str(profile.path))
            if "profile" in profile.backend_options(name):
                raise InputFileError(
                    profile.path, f"backends.{name}.profile: a profile cannot choose another (use a run config or -B)"
                )
            layers.append((str(profile.path), profile.backend_options(name)))
        layers += [(config.where, config_layer), ("", cli_layer)]
        options = merge_options(cls.Options, layers, plugin=plugin)
        sources = {key: where for where, raw in layers for key in (raw or {})}  # the last layer wins
        planned.append(PlannedBackend(name, cls(options), profile, sources))
    return planned


def run_in_own_processes(planned: list[PlannedBackend]) -> None:
    """Move each backend that may run in a process of its own there (before it opens)."""
    from convodrive.scheduler.process import ProcessBackend

    for item in planned:
        if item.backend.may_run_in_process:
            item.backend = ProcessBackend(item.backend)


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
            except UserError as exc:
                raise item.where(exc) from None
            except Exception as exc:  # hardware or driver fault: this backend only
                failed[item.name] = error_line(exc)
                log.error("%s: failed to open (%s); the run goes on without it", item.name, failed[item.name])
                continue
            log.info("%s: open", item.name)
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


def _profile_for(cls: type[Backend], config: RunConfig, chosen: str | None) -> Any:
    """The profile a backend drives (see the module's docstring); None for canonical motion."""
    if cls.default_profile is None:
        return None
    from convodrive.retargeting import load_profile

    if chosen:
        return load_profile(chosen)
    if config.profile is not None:
        return config.profile
    return load_profile(cls.default_profile)


def safe_outputs(backend: Backend) -> list[Path]:
    try:
        return list(backend.outputs())
    except Exception:
        return []
