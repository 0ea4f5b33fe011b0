"""Plugin discovery through entry points (``convodrive.generators``, ``convodrive.backends``).

A third-party package adds a generator or a backend by declaring an entry point in one of these
groups; nothing in this repository changes. Built-ins are registered the same way, in
pyproject.toml, so there is one mechanism for all.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.util
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from convodrive.plumbing.errors import UserError
from convodrive.plumbing.text import clip_value

GENERATOR_GROUP = "convodrive.generators"
BACKEND_GROUP = "convodrive.backends"


@dataclasses.dataclass(frozen=True)
class PluginInfo:
    name: str
    group: str
    target: str
    description: str
    available: bool
    problem: str = ""


def _entry_points(group: str) -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=group)}


def plugin_kind(group: str) -> str:
    return "generator" if group == GENERATOR_GROUP else "backend"


def plugin_names(group: str) -> list[str]:
    return sorted(_entry_points(group))


def unknown_plugin(group: str, name: str) -> str:
    """ "unknown backend 'mujco' (did you mean 'mujoco'?)", or the list of those installed."""
    names = plugin_names(group)
    close = difflib.get_close_matches(str(name), names, n=1, cutoff=0.6)
    hint = f"did you mean '{close[0]}'?" if close else f"available: {', '.join(names) or 'none installed'}"
    return f"unknown {plugin_kind(group)} {clip_value(name)} ({hint})"


def load_plugin(group: str, name: str) -> type:
    """The plugin class named ``name``; ``UserError`` if it is unknown or cannot be imported."""
    eps = _entry_points(group)
    kind = plugin_kind(group)
    if name not in eps:
        raise UserError(unknown_plugin(group, name))
    try:
        cls = eps[name].load()
    except ImportError as exc:
        raise UserError(f"{kind} '{name}' cannot be loaded: {exc} (is its extra installed?)") from None
    missing = missing_modules(cls)
    if missing:
        extra = getattr(cls, "extra", "")
        hint = f"pip install 'convodrive[{extra}]'" if extra else "install its dependencies"
        raise UserError(f"{kind} '{name}' needs {', '.join(missing)}, which is not installed ({hint})")
    return cls


def missing_modules(cls: type) -> list[str]:
    """The modules a plugin declares in ``requires`` that this Python cannot import."""
    return [m for m in getattr(cls, "requires", ()) if importlib.util.find_spec(m) is None]


def list_plugins(group: str) -> list[PluginInfo]:
    infos = []
    for name, ep in sorted(_entry_points(group).items()):
        try:
            cls: Any = ep.load()
            missing = missing_modules(cls)
            problem = f"needs {', '.join(missing)} (extra '{getattr(cls, 'extra', '')}')" if missing else ""
            infos.append(PluginInfo(name, group, ep.value, getattr(cls, "description", "") or "", not missing, problem))
        except Exception as exc:  # a broken third-party plugin must not break the listing
            infos.append(PluginInfo(name, group, ep.value, "", False, f"{exc.__class__.__name__}: {exc}"))
    return infos
