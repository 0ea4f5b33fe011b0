"""Plugin options, declared once (DESIGN, "Plugins"): type, default, range and help in one place.

A plugin declares its options as a frozen dataclass of ``option(...)`` fields and names it in its
``Options`` class attribute. The CLI (``-G``/``-B``), YAML sections, robot profiles and
``convodrive plugins NAME`` all read that one declaration:

    @dataclasses.dataclass(frozen=True)
    class RenderOptions(PluginOptions):
        camera: str = option("upper", choices=("full", "upper", "face"), help="Which camera frames the avatar.")
        fps_limit: float = option(30.0, low=1, high=120, help="...")

``parse_options`` turns a raw mapping into an instance, or raises one ``UserError`` line that names
the plugin, the key, the problem and, for a typo, the option meant. Numbers must be finite, counts
and sizes are bounded, and a value is never echoed longer than a line.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from convodrive.plumbing.errors import UserError
from convodrive.plumbing.text import clip_value

T = TypeVar("T", bound="PluginOptions")


@dataclasses.dataclass(frozen=True)
class PluginOptions:
    """Base of every plugin's options dataclass. Subclasses add ``option(...)`` fields only."""


def option(
    default: Any,
    *,
    help: str,
    low: float | None = None,
    high: float | None = None,
    choices: tuple[Any, ...] | None = None,
    infinite: bool = False,
    max_items: int = 1024,
) -> Any:
    """One declared option: ``default`` and its ``help`` text. ``low``/``high`` bound a number (or
    each number of a list), ``choices`` lists the allowed values, ``infinite`` admits ±inf, and
    ``max_items`` bounds the length of a list."""
    meta = {"help": help, "low": low, "high": high, "choices": choices, "infinite": infinite, "max_items": max_items}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: _copy(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _copy(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _copy(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy(v) for v in value]
    return value


@dataclasses.dataclass(frozen=True)
class OptionInfo:
    """What ``convodrive plugins NAME`` prints for one option."""

    name: str
    type: str
    default: Any
    help: str
    low: float | None
    high: float | None
    choices: tuple[Any, ...] | None

    def describe(self) -> str:
        bounds = ""
        if self.choices:
            bounds = " one of " + ", ".join(str(c) for c in self.choices)
        elif self.low is not None or self.high is not None:
            lo = "" if self.low is None else f"{self.low:g}"
            hi = "" if self.high is None else f"{self.high:g}"
            bounds = f" in [{lo}, {hi}]"
        return f"{self.name} ({self.type}{bounds}, default {self.default!r}): {self.help}"


def describe_options(cls: type[PluginOptions]) -> list[OptionInfo]:
    hints = typing.get_type_hints(cls)
    infos = []
    for f in dataclasses.fields(cls):
        factory = typing.cast(typing.Callable[[], Any], f.default_factory)
        default = f.default if f.default is not dataclasses.MISSING else factory()
        m = f.metadata
        infos.append(
            OptionInfo(
                f.name,
                _type_name(hints[f.name]),
                default,
                m.get("help", ""),
                m.get("low"),
                m.get("high"),
                m.get("choices"),
            )
        )
    return infos


def parse_options(cls: type[T], raw: Mapping[str, Any] | None, *, plugin: str, where: str = "") -> T:
    """Validate ``raw`` against ``cls`` and fill the defaults. ``plugin`` names it for messages
    ("backend dynamixel"); ``where`` names the file the values came from, when they came from one."""
    values = check_options(cls, raw, plugin=plugin, where=where)
    return cls(**values)


def check_options(
    cls: type[PluginOptions], raw: Mapping[str, Any] | None, *, plugin: str, where: str = ""
) -> dict[str, Any]:
    """Validate a partial mapping (one layer of a merge: a profile, a config file, the command
    line) and return it with values converted to their declared types."""
    label = f"{where}: {plugin}" if where else plugin
    if raw is None:
        return {}
    if not isinstance(raw, Mapping):
        raise UserError(f"{label}: options must be a mapping of names to values, got {clip_value(raw)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in fields:
            raise UserError(f"{label}: unknown option {clip_value(key)}{_did_you_mean(str(key), fields)}")
        f = fields[key]
        out[key] = _convert(value, hints[key], f.metadata, f"{label}: option '{key}'")
    return out


def _did_you_mean(key: str, fields: Mapping[str, Any]) -> str:
    close = difflib.get_close_matches(key, list(fields), n=1, cutoff=0.6)
    if close:
        return f" (did you mean '{close[0]}'?)"
    return f" (known: {', '.join(fields)})" if fields else " (it takes no options)"


def _convert(value: Any, hint: Any, meta: Mapping[str, Any], label: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _convert(value, inner[0], meta, label)
        for candidate in inner:  # the first type the value fits
            try:
                return _convert(value, candidate, meta, label)
            except UserError:
                continue
        raise UserError(f"{label} must be {' or '.join(_type_name(a) for a in inner)}, got {clip_value(value)}")
    if hint is bool:
        if not isinstance(value, bool):
            raise UserError(f"{label} must be true or false, got {clip_value(value)}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not float(value).is_integer():
            raise UserError(f"{label} must be a whole number, got {clip_value(value)}")
        return _bounded(int(value), meta, label)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UserError(f"{label} must be a number, got {clip_value(value)}")
        number = float(value)
        if math.isnan(number) or (math.isinf(number) and not meta.get("infinite")):
            raise UserError(f"{label} must be a finite number, got {clip_value(value)}")
        return _bounded(number, meta, label)
    if hint is str:
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise UserError(f"{label} must be text, got {clip_value(value)}")
        return _chosen(str(value), meta, label)
    if hint is Path:
        if not isinstance(value, (str, Path)) or not str(value):
            raise UserError(f"{label} must be a file path, got {clip_value(value)}")
        return Path(value)
    if origin in (list, tuple) or hint in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise UserError(f"{label} must be a list, got {clip_value(value)}")
        if len(value) > meta.get("max_items", 1024):
            raise UserError(f"{label} may hold at most {meta.get('max_items', 1024)} items, got {len(value)}")
        item = args[0] if args else Any
        items = [v if item is Any else _convert(v, item, meta, f"{label} item") for v in value]
        return items if origin is list or hint is list else tuple(items)
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise UserError(f"{label} must be a mapping, got {clip_value(value)}")
        return dict(value)
    if hint is Any:
        return value
    raise TypeError(f"{label}: unsupported option type {hint!r}")  # a plugin author's mistake


def _bounded(number: float, meta: Mapping[str, Any], label: str) -> Any:
    low, high = meta.get("low"), meta.get("high")
    if (low is not None and number < low) or (high is not None and number > high):
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        raise UserError(f"{label} must be between {lo} and {hi}, got {clip_value(number)}")
    return _chosen(number, meta, label)


def _chosen(value: Any, meta: Mapping[str, Any], label: str) -> Any:
    choices = meta.get("choices")
    if choices and value not in choices:
        close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1, cutoff=0.6)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise UserError(f"{label} must be one of {', '.join(map(str, choices))}, got {clip_value(value)}{hint}")
    return value


def _type_name(hint: Any) -> str:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(hint) if a is not type(None)) + " or null"
    names = {bool: "bool", int: "int", float: "float", str: "text", Path: "path", list: "list", dict: "mapping"}
    if hint in names:
        return names[hint]
    if origin in names:
        return names[origin]
    return getattr(hint, "__name__", str(hint))
