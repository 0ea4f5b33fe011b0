"""The one options mechanism: declared types, ranges and help; one-line errors naming the file,
the plugin and the key; layers; nested settings; flags made from the declaration."""

from __future__ import annotations

import argparse
import dataclasses
import math
import typing
from pathlib import Path

import pytest

from convodrive.plugins import BACKEND_GROUP, GENERATOR_GROUP, load_plugin, plugin_names
from convodrive.plugins.option_help import add_option_arguments, describe_options, option_arguments
from convodrive.plugins.options import (
    REQUIRED,
    PluginOptions,
    coerce_options,
    merge_options,
    option,
    parse_options,
)
from convodrive.plumbing.errors import UserError


@dataclasses.dataclass(frozen=True)
class Joint(PluginOptions):
    id: int = option(REQUIRED, low=0, high=252, help="servo id")
    direction: int = option(1, choices=(1, -1), help="sign")


@dataclasses.dataclass(frozen=True)
class Head(PluginOptions):
    port: str = option("", help="serial port")
    read_rate: float = option(10.0, low=0.5, high=100, help="reads per second")
    watchdog_s: float = option(0.5, low=0.05, high=10, help="watchdog")
    limit: float = option(math.inf, low=0, infinite=True, help="may be unlimited")
    verbose: bool = option(False, help="say more")
    model: Path | None = option(None, help="a file")
    gains: list[float] = option([1.0], low=0, high=10, max_items=3, help="per joint")
    joints: dict[str, Joint] | None = option(None, max_items=4, help="per joint")
    low_db: float = option(-48.0, low=-100, high=0, help="off")
    high_db: float = option(-40.0, low=-100, high=0, help="on")

    def __post_init__(self) -> None:
        if self.low_db > self.high_db:
            raise ValueError("low_db must not exceed high_db")


def fails(raw: dict, *needles: str, where: str = "") -> str:
    with pytest.raises(UserError) as info:
        parse_options(Head, raw, plugin="backend head", where=where)
    message = str(info.value)
    assert "\n" not in message and len(message) < 300, message
    for needle in needles:
        assert needle in message, (needle, message)
    return message


def test_defaults_and_types() -> None:
    opts = parse_options(Head, {"read_rate": 20, "model": "m.xml", "joints": {"pan": {"id": 3}}}, plugin="backend head")
    assert opts.read_rate == 20.0 and isinstance(opts.read_rate, float)
    assert opts.model == Path("m.xml") and opts.watchdog_s == 0.5 and opts.gains == [1.0]
    assert opts.joints == {"pan": Joint(id=3, direction=1)}
    assert parse_options(Head, None, plugin="x") == Head()
    assert (
        Head().as_dict()["model"] is None and parse_options(Head, {"model": "a"}, plugin="x").as_dict()["model"] == "a"
    )


@pytest.mark.parametrize(
    "raw, needles",
    [
        ({"watchdog_s": "soon"}, ["backend head: option 'watchdog_s' must be a number, got 'soon'"]),
        ({"watchdog_s": -1}, ["option 'watchdog_s' must be between 0.05 and 10, got -1"]),
        ({"read_rate": math.nan}, ["must be a finite number"]),
        ({"read_rate": math.inf}, ["must be a finite number"]),
        ({"raed_rate": 5}, ["unknown option 'raed_rate'", "did you mean 'read_rate'?"]),
        ({"verbose": "yes please"}, ["must be true or false"]),
        ({"gains": [1, 2, 3, 4]}, ["at most 3 items"]),
        ({"gains": [1, 20]}, ["option 'gains[1]' must be between 0 and 10"]),
        ({"joints": {"pan": {"id": 300}}}, ["option 'joints.pan.id' must be between 0 and 252"]),
        ({"joints": {"pan": {"direction": 1}}}, ["option 'joints.pan.id' is required"]),
        ({"joints": {"pan": {"idd": 1}}}, ["unknown option 'joints.pan.idd'", "did you mean 'id'?"]),
        ({"joints": {"pan": 5}}, ["option 'joints.pan' must be a mapping"]),
        ({"joints": {"pan": {"id": 1, "direction": 2}}}, ["must be one of 1, -1"]),
        ({"low_db": -10}, ["backend head: low_db must not exceed high_db"]),
        ({"port": ["a"]}, ["must be text"]),
        ({"port": "x" * 5000}, ["at most 4096 characters"]),
    ],
)
def test_bad_values_are_one_line_naming_plugin_and_key(raw: dict, needles: list[str]) -> None:
    fails(raw, *needles)


def test_infinite_only_where_declared() -> None:
    assert parse_options(Head, {"limit": math.inf}, plugin="x").limit == math.inf
    fails({"limit": math.nan}, "finite")


def test_a_file_is_named_and_a_huge_value_stays_one_short_line() -> None:
    bomb = [["lol"] * 1000] * 1000  # what an alias bomb would hand over, shared rows
    message = fails({"port": bomb}, "head.yaml: backend head: option 'port' must be text", where="head.yaml")
    assert len(message) < 200


def test_not_a_mapping() -> None:
    with pytest.raises(
        UserError, match=r"run.yaml: backend record: options must be a mapping of names to values, got 5"
    ):
        parse_options(Head, 5, plugin="backend record", where="run.yaml")  # type: ignore[arg-type]


def test_layers_merge_in_order_and_each_names_its_file() -> None:
    opts = merge_options(
        Head,
        [("profile.yaml", {"port": "/dev/a", "read_rate": 5}), ("run.yaml", {"read_rate": 7}), ("", {"verbose": True})],
        plugin="backend head",
    )
    assert (opts.port, opts.read_rate, opts.verbose) == ("/dev/a", 7.0, True)
    with pytest.raises(UserError, match=r"^run.yaml: backend head: option 'read_rate'"):
        merge_options(
            Head, [("profile.yaml", {"port": "/dev/a"}), ("run.yaml", {"read_rate": "fast"})], plugin="backend head"
        )
    with pytest.raises(UserError, match=r"^backend head: unknown option 'raed_rate'"):
        merge_options(Head, [("profile.yaml", {}), ("", {"raed_rate": 1})], plugin="backend head")
    # a check across options names the files whose values met
    with pytest.raises(UserError, match=r"^a.yaml, b.yaml: backend head: low_db must not exceed"):
        merge_options(Head, [("a.yaml", {"low_db": -30}), ("b.yaml", {"high_db": -35})], plugin="backend head")


def test_coerce_takes_parsed_or_raw_and_refuses_another_plugins_options() -> None:
    opts = Head(port="p")
    assert coerce_options(Head, opts, plugin="x") is opts
    assert coerce_options(Head, {"port": "q"}, plugin="x").port == "q"
    with pytest.raises(TypeError):
        coerce_options(Head, Joint(id=1), plugin="x")


def test_describe_lists_nested_settings() -> None:
    infos = {i.name: i for i in describe_options(Head)}
    assert infos["watchdog_s"].describe() == "watchdog_s (float, from 0.05 to 10; default 0.5): watchdog"
    assert infos["joints.NAME.id"].required and infos["joints.NAME.id"].kind() == "int, from 0 to 252"
    assert infos["joints.NAME.direction"].kind() == "int, one of 1, -1"
    assert infos["limit"].default_text() == "inf"


def test_flags_come_from_the_declaration() -> None:
    parser = argparse.ArgumentParser()
    add_option_arguments(parser, Head, ["port", "read_rate", "verbose"])
    assert "reads per second (float, from 0.5 to 100)" in parser.format_help()
    args = parser.parse_args(["--read-rate", "20", "--verbose"])
    assert option_arguments(args, ["port", "read_rate", "verbose"]) == {"read_rate": 20, "verbose": True}
    assert option_arguments(parser.parse_args([]), ["port", "read_rate"]) == {}  # unset: the profile's apply
    with pytest.raises(UserError, match="option 'read_rate' must be between"):
        merge_options(
            Head, [("", option_arguments(parser.parse_args(["--read-rate", "1e9"]), ["read_rate"]))], plugin="x"
        )


def test_a_text_flag_keeps_its_text() -> None:
    """``--port no`` is the text "no" (YAML would read false) and ``1:30`` stays itself (YAML 1.1
    reads 90); flags of other types are still read as YAML."""
    parser = argparse.ArgumentParser()
    add_option_arguments(parser, Head, ["port", "model", "gains"], show_defaults=True)
    for text in ("no", "1:30", "0x10", "null"):
        given = option_arguments(parser.parse_args(["--port", text]), ["port"])
        assert merge_options(Head, [("", given)], plugin="x").port == text
    args = parser.parse_args(["--model", "yes", "--gains", "[1, 2.5]"])
    options = merge_options(Head, [("", option_arguments(args, ["model", "gains"]))], plugin="x")
    assert options.model == Path("yes") and options.gains == [1.0, 2.5]
    assert "(float, from 0.5 to 100; default 10.0)" not in parser.format_help()  # only the flags asked for
    assert '(text; default "")' in parser.format_help()


# -------------------------------------------------------------------------------- every built-in
def _builtin_plugins() -> list[tuple[str, type]]:
    found = []
    for group in (GENERATOR_GROUP, BACKEND_GROUP):
        for name in plugin_names(group):
            try:
                cls = load_plugin(group, name)
            except UserError:
                continue
            if cls.__module__.startswith("convodrive."):
                found.append((name, cls))
    return found


def _all_options(cls: type[PluginOptions]) -> list[tuple[str, typing.Any, dict]]:
    out = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        out.append((f.name, hints[f.name], dict(f.metadata)))
        for inner in (hints[f.name], *typing.get_args(hints[f.name])):
            args = typing.get_args(inner)
            nested = args[1] if typing.get_origin(inner) is dict else inner
            if isinstance(nested, type) and issubclass(nested, PluginOptions):
                out += [(f"{f.name}.{n}", h, m) for n, h, m in _all_options(nested)]
    return out


@pytest.mark.mujoco
@pytest.mark.gl
@pytest.mark.hardware
def test_every_builtin_plugin_declares_its_options() -> None:
    plugins = dict(_builtin_plugins())
    assert {"procedural", "replay", "record", "render", "mujoco", "dynamixel", "maestro"} <= set(plugins)
    for name, cls in plugins.items():
        assert cls.Options is PluginOptions or issubclass(cls.Options, PluginOptions), name
        for key, _, meta in _all_options(cls.Options):
            assert meta.get("help"), f"{name}.{key} has no help"


def test_every_number_is_bounded() -> None:
    """Defect 2: a count or size without a bound let --samples 99999999999 kill the machine."""
    for name, cls in _builtin_plugins():
        for key, hint, meta in _all_options(cls.Options):
            numeric = {int, float} & {hint, *typing.get_args(hint)}
            if numeric:
                bounded = meta.get("choices") or (meta.get("low") is not None and meta.get("high") is not None)
                assert bounded, f"{name}.{key} is a number without a range"
