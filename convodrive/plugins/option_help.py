"""Options as a user reads them: the listing ``convodrive plugins NAME`` prints, and command-line
flags that carry the declared help (``convodrive.plugins.options`` declares and checks them)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from convodrive.plugins.options import REQUIRED, PluginOptions, range_text, type_name
from convodrive.plumbing.safe_yaml import parse_scalar
from convodrive.plumbing.text import clip_value


@dataclasses.dataclass(frozen=True)
class OptionInfo:
    """What ``convodrive plugins NAME`` prints for one option; nested settings are listed as
    ``joints.NAME.id``."""

    name: str
    type: str
    default: Any
    help: str
    low: float | None = None
    high: float | None = None
    choices: tuple[Any, ...] | None = None

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def bounds(self) -> str:
        if self.choices:
            return "one of " + ", ".join(_show(c) for c in self.choices)
        if self.low is not None or self.high is not None:
            return range_text(self.low, self.high).replace("between", "from").replace(" and ", " to ")
        return ""

    def kind(self) -> str:
        """``int, from 16 to 4096``: the type and what it admits."""
        bounds = self.bounds()
        return f"{self.type}, {bounds}" if bounds else self.type

    def default_text(self) -> str:
        return "required" if self.required else _show(self.default)

    def describe(self) -> str:
        default = "required" if self.required else f"default {self.default_text()}"
        return f"{self.name} ({self.kind()}; {default}): {self.help}"


def _show(value: Any) -> str:
    if value is None:
        return "null"
    if value == "":
        return '""'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if isinstance(value, (dict, list)) and not value:
        return "{}" if isinstance(value, dict) else "[]"
    return str(value) if isinstance(value, (int, float, str)) else clip_value(value)


def describe_options(cls: type[PluginOptions], prefix: str = "") -> list[OptionInfo]:
    hints = typing.get_type_hints(cls)
    infos = []
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = REQUIRED
        m = f.metadata
        name = prefix + f.name
        hint = hints[f.name]
        infos.append(
            OptionInfo(name, type_name(hint), default, m.get("help", ""), m.get("low"), m.get("high"), m.get("choices"))
        )
        nested = _nested(hint)
        if nested is not None:
            infos += describe_options(nested, f"{name}.NAME." if _is_mapping(hint) else f"{name}.")
    return infos


def _nested(hint: Any) -> type[PluginOptions] | None:
    """The options dataclass inside ``hint`` (``X``, ``X | None``, ``dict[str, X]``), if any."""
    for candidate in (hint, *typing.get_args(hint)):
        if isinstance(candidate, type) and issubclass(candidate, PluginOptions):
            return candidate
        if typing.get_origin(candidate) is dict:
            return _nested(typing.get_args(candidate)[1])
    return None


def _is_mapping(hint: Any) -> bool:
    return any(typing.get_origin(c) is dict for c in (hint, *typing.get_args(hint)))


# ------------------------------------------------------------------------------------ flags
def add_option_arguments(
    parser: argparse.ArgumentParser,
    cls: type[PluginOptions],
    names: Sequence[str],
    *,
    show_defaults: bool = False,
) -> None:
    """Command-line flags (``--latency-ms``) for some of a plugin's options, with the declared help.
    Their values stay unset unless given, so a profile's values apply (say the defaults in the help
    with ``show_defaults`` where nothing else does); read them with ``option_arguments`` and check
    them as a layer of ``merge_options`` or ``check_options``."""
    infos = {i.name: i for i in describe_options(cls)}
    hints = typing.get_type_hints(cls)
    for name in names:
        info = infos[name]
        default = f"; default {info.default_text()}" if show_defaults else ""
        text = f"{info.help} ({info.kind()}{default})"
        flag = "--" + name.replace("_", "-")
        if info.type == "bool":
            parser.add_argument(flag, dest=name, default=None, action=argparse.BooleanOptionalAction, help=text)
        else:
            parser.add_argument(
                flag, dest=name, default=None, metavar=name.upper(), type=_flag_reader(hints[name]), help=text
            )


def _flag_reader(hint: Any) -> Any:
    """A flag's text as its option takes it: verbatim for text and paths (``--labels no`` is the
    caption "no", not false), read as YAML otherwise (numbers, booleans, lists)."""
    kinds = (
        set(typing.get_args(hint)) - {type(None)}
        if typing.get_origin(hint) in (typing.Union, types.UnionType)
        else {hint}
    )
    return str if kinds in ({str}, {Path}) else parse_scalar


def option_arguments(args: argparse.Namespace, names: Sequence[str]) -> dict[str, Any]:
    """The flags of ``add_option_arguments`` that were given, as a layer for ``merge_options``."""
    return {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
