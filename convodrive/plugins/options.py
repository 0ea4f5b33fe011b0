"""Plugin options, declared once: type, default, range and help in one place.

A plugin declares its options as a frozen dataclass of ``option(...)`` fields and names it in its
``Options`` class attribute; the Generator and Backend base classes parse what they are given into
that dataclass, so a plugin only ever sees a typed, checked object:

    @dataclasses.dataclass(frozen=True)
    class RenderOptions(PluginOptions):
        camera: str = option("upper", choices=("full", "upper", "face"), help="Which camera frames the avatar.")
        fps_limit: float = option(30.0, low=1, high=120, help="...")

The command line (``-G``/``-B``, or flags made by ``add_option_arguments``), YAML sections, robot
profiles and ``convodrive plugins NAME`` all read that one declaration. Values arrive in layers
(a profile, a run config, the command line); ``merge_options`` checks each layer on its own, so a
bad value is one ``UserError`` line naming the file it came from, the plugin, the key and the
problem, with the option meant when the key is a typo. Numbers must be finite unless declared
``infinite``, counts, sizes, lists and text are bounded, nested settings (a servo per joint) are
dataclasses of their own, checked the same way, and a value is never echoed longer than a line.
Checks that involve several options live in the dataclass's ``__post_init__``, which raises
``ValueError`` with the problem.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from convodrive.plumbing.errors import UserError
from convodrive.plumbing.safe_yaml import number_text
from convodrive.plumbing.text import clip_value

T = TypeVar("T", bound="PluginOptions")

MAX_ITEMS = 1024
"""Longest list or mapping an option takes unless it declares ``max_items``."""
MAX_CHARS = 4096
"""Longest text an option takes."""


class _Required:
    def __repr__(self) -> str:
        return "required"


REQUIRED: Any = _Required()
"""The default of an option that has none: the user must give it (put such fields first)."""


@dataclasses.dataclass(frozen=True)
class PluginOptions:
    """Base of every plugin's options dataclass; on its own, the options of a plugin that has none."""

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-able values (paths as text), for run reports."""
        return {k: _plain(v) for k, v in dataclasses.asdict(self).items()}


def _plain(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def option(
    default: Any,
    *,
    help: str,
    low: float | None = None,
    high: float | None = None,
    choices: tuple[Any, ...] | None = None,
    infinite: bool = False,
    max_items: int = MAX_ITEMS,
) -> Any:
    """One declared option: ``default`` (or ``REQUIRED``) and its ``help`` text. ``low``/``high``
    bound a number (or each number of a list), ``choices`` lists the allowed values, ``infinite``
    admits ±inf, and ``max_items`` bounds the length of a list or mapping."""
    meta = {"help": help, "low": low, "high": high, "choices": choices, "infinite": infinite, "max_items": max_items}
    if default is REQUIRED:
        return dataclasses.field(metadata=meta)
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: _copy(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _copy(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _copy(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy(v) for v in value]
    return value


# ------------------------------------------------------------------------------------ parsing
def parse_options(cls: type[T], raw: Mapping[str, Any] | None, *, plugin: str, where: str = "") -> T:
    """Validate ``raw`` against ``cls`` and fill the defaults. ``plugin`` names it for messages
    ("backend dynamixel"); ``where`` names the file the values came from, when they came from one."""
    return merge_options(cls, [(where, raw)], plugin=plugin)


def merge_options(cls: type[T], layers: Iterable[tuple[str, Mapping[str, Any] | None]], *, plugin: str) -> T:
    """Options from layers, lowest first (a profile, a run config, the command line): each layer is
    checked on its own and names its own file; a later layer replaces an option of an earlier one."""
    merged: dict[str, Any] = {}
    sources: list[str] = []
    for where, raw in layers:
        values = check_options(cls, raw, plugin=plugin, where=where)
        merged.update(values)
        if values and where and where not in sources:
            sources.append(where)
    return _build(cls, merged, ", ".join(sources), plugin, "")


def coerce_options(cls: type[T], options: T | Mapping[str, Any] | None, *, plugin: str) -> T:
    """What a plugin's constructor was given, as its options: already parsed, or a raw mapping."""
    if isinstance(options, cls):
        return options
    if isinstance(options, PluginOptions):
        raise TypeError(f"{plugin} takes {cls.__name__}, not {type(options).__name__}")  # a programming error
    return parse_options(cls, options, plugin=plugin)


def check_options(
    cls: type[PluginOptions], raw: Mapping[str, Any] | None, *, plugin: str, where: str = ""
) -> dict[str, Any]:
    """Validate a partial mapping (one layer of a merge: a profile, a config file, the command
    line) and return it with values converted to their declared types."""
    prefix = f"{where}: {plugin}" if where else plugin
    if raw is None:
        return {}
    return _check(cls, raw, prefix, "")


def _check(cls: type[PluginOptions], raw: Any, prefix: str, path: str) -> dict[str, Any]:
    if not isinstance(raw, Mapping):
        what = f"option '{path}'" if path else "options"
        raise UserError(f"{prefix}: {what} must be a mapping of names to values, got {clip_value(raw)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    out: dict[str, Any] = {}
    for key, value in raw.items():
        key_path = f"{path}.{key}" if path else str(key)
        if key not in fields:
            raise UserError(f"{prefix}: unknown option {clip_value(key_path)}{_did_you_mean(str(key), fields)}")
        f = fields[key]
        out[key] = _convert(value, hints[key], f.metadata, prefix, key_path)
    return out


def _build(cls: type[T], values: dict[str, Any], where: str, plugin: str, path: str) -> T:
    prefix = f"{where}: {plugin}" if where else plugin
    for f in dataclasses.fields(cls):
        if f.name not in values and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            key_path = f"{path}.{f.name}" if path else f.name
            raise UserError(f"{prefix}: option '{key_path}' is required ({f.metadata.get('help', '')})")
    try:
        return cls(**values)
    except ValueError as exc:  # a check across options, from the dataclass's __post_init__
        at = f"option '{path}': " if path else ""
        raise UserError(f"{prefix}: {at}{exc}") from None


def _did_you_mean(key: str, fields: Mapping[str, Any]) -> str:
    close = difflib.get_close_matches(key, list(fields), n=1, cutoff=0.6)
    if close:
        return f" (did you mean '{close[0]}'?)"
    return f" (known: {', '.join(fields)})" if fields else " (it takes no options)"


def _convert(value: Any, hint: Any, meta: Mapping[str, Any], prefix: str, path: str) -> Any:
    label = f"{prefix}: option '{path}'"
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _convert(value, inner[0], meta, prefix, path)
        for candidate in inner:  # the first type the value fits
            try:
                return _convert(value, candidate, meta, prefix, path)
            except UserError:
                continue
        raise UserError(f"{label} must be {' or '.join(type_name(a) for a in inner)}, got {clip_value(value)}")
    if isinstance(hint, type) and issubclass(hint, PluginOptions):
        return _build(hint, _check(hint, value, prefix, path), "", prefix, path)
    if hint is bool:
        if not isinstance(value, bool):
            raise UserError(f"{label} must be true or false, got {clip_value(value)}")
        return value
    if hint in (int, float):
        value = number_text(value)
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
        return _chosen(_short(str(value), label), meta, label)
    if hint is Path:
        if not isinstance(value, (str, Path)) or not str(value):
            raise UserError(f"{label} must be a file path, got {clip_value(value)}")
        return Path(_short(str(value), label))
    if origin in (list, tuple) or hint in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise UserError(f"{label} must be a list, got {clip_value(value)}")
        _count(value, meta, label)
        item = args[0] if args else Any
        items = [v if item is Any else _convert(v, item, meta, prefix, f"{path}[{i}]") for i, v in enumerate(value)]
        return items if origin is list or hint is list else tuple(items)
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise UserError(f"{label} must be a mapping, got {clip_value(value)}")
        _count(value, meta, label)
        item = args[1] if len(args) == 2 else Any
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise UserError(f"{label} must be keyed by names, got the key {clip_value(k)}")
            out[k] = v if item is Any else _convert(v, item, meta, prefix, f"{path}.{k}")
        return out
    if hint is Any:
        return value
    raise TypeError(f"{label}: unsupported option type {hint!r}")  # a plugin author's mistake


def _short(text: str, label: str) -> str:
    if len(text) > MAX_CHARS:
        raise UserError(f"{label} must be at most {MAX_CHARS} characters, got {len(text)}")
    return text


def _count(value: Sequence[Any] | Mapping[Any, Any], meta: Mapping[str, Any], label: str) -> None:
    limit = meta.get("max_items", MAX_ITEMS)
    if len(value) > limit:
        raise UserError(f"{label} may hold at most {limit} items, got {len(value)}")


def _bounded(number: float, meta: Mapping[str, Any], label: str) -> Any:
    low, high = meta.get("low"), meta.get("high")
    if (low is not None and number < low) or (high is not None and number > high):
        raise UserError(f"{label} must be {range_text(low, high)}, got {clip_value(number)}")
    return _chosen(number, meta, label)


def range_text(low: float | None, high: float | None) -> str:
    if low is not None and high is not None:
        return f"between {_number(low)} and {_number(high)}"
    return f"at least {_number(low)}" if low is not None else f"at most {_number(high)}"


def _number(x: float | None) -> str:
    """``4500000`` rather than ``4.5e+06``; ``0.05`` as itself."""
    if x is None:
        return ""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _chosen(value: Any, meta: Mapping[str, Any], label: str) -> Any:
    choices = meta.get("choices")
    if choices and value not in choices:
        close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1, cutoff=0.6)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise UserError(f"{label} must be one of {', '.join(map(str, choices))}, got {clip_value(value)}{hint}")
    return value


def type_name(hint: Any) -> str:
    """How a user reads an option's type (``int``, ``list of text``, ``float or null``)."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        names = [type_name(a) for a in typing.get_args(hint) if a is not type(None)]
        return " or ".join(names) + (" or null" if type(None) in typing.get_args(hint) else "")
    if isinstance(hint, type) and issubclass(hint, PluginOptions):
        return "settings"
    simple = {bool: "bool", int: "int", float: "float", str: "text", Path: "path", list: "list", dict: "mapping"}
    if origin is dict:
        return f"mapping of name to {type_name(typing.get_args(hint)[1])}"
    if origin in (list, tuple) and typing.get_args(hint):
        return f"list of {type_name(typing.get_args(hint)[0])}"
    if hint in simple:
        return simple[hint]
    if origin in simple:
        return simple[origin]
    return getattr(hint, "__name__", str(hint))


# ------------------------------------------------------------------------------------ shared checks
def check_file_name(key: str, value: str, suffix: str = "") -> None:
    """For ``__post_init__``: ``value`` must be a plain file name (no folder), ending in ``suffix``."""
    if not value or "/" in value or "\\" in value or value.startswith(".") or len(value) > 255:
        raise ValueError(f"option '{key}' must be a plain file name, got {clip_value(value)}")
    if suffix and not value.lower().endswith(suffix):
        raise ValueError(f"option '{key}' must end in {suffix}, got {clip_value(value)}")
