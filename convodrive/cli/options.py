"""Argument types shared by subcommands: each turns bad input into a one-line argparse error."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from convodrive.audio.source import ChannelMap
from convodrive.pipeline import DEFAULT_GENERATOR
from convodrive.plumbing.errors import UserError
from convodrive.plumbing.safe_yaml import parse_scalar
from convodrive.plumbing.text import clip_value


def channel_map(text: str) -> ChannelMap:
    try:
        return ChannelMap.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def name_list(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected one or more names separated by commas")
    return names


def int_in(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: a whole number from ``low`` to ``high`` (every count is bounded)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {clip_value(text)}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected a whole number from {low} to {high}, got {value}")
        return value

    return parse


def number_in(low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a finite number from ``low`` to ``high``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {clip_value(text)}") from None
        if not low <= value <= high:  # also false for nan
            raise argparse.ArgumentTypeError(f"expected a number from {low:g} to {high:g}, got {clip_value(text)}")
        return value

    return parse


def key_value(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` with VALUE read as YAML, so numbers and booleans keep their types."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {clip_value(text)}")
    return key.strip(), parse_scalar(raw)


def scoped_key_value(scope: str, example: str) -> Callable[[str], tuple[str, str, Any]]:
    """An argparse type: ``SCOPE.KEY=VALUE`` (e.g. a backend's or a compared method's option)."""

    def parse(text: str) -> tuple[str, str, Any]:
        key, value = key_value(text)
        name, dot, option = key.partition(".")
        if not dot or not name or not option:
            raise argparse.ArgumentTypeError(f"expected {scope}.KEY=VALUE (e.g. {example}), got {clip_value(text)}")
        return name, option, value

    return parse


backend_key_value = scoped_key_value("BACKEND", "render.camera=face")


def add_motion_options(p: argparse.ArgumentParser) -> None:
    """The options every run shares: generator, backends, config, output folder, seed, --motion, -G, -B."""
    p.add_argument("--generator", default=DEFAULT_GENERATOR, help=f"generator plugin (default: {DEFAULT_GENERATOR})")
    p.add_argument(
        "--backend",
        type=name_list,
        default=("record",),
        metavar="NAME[,NAME]",
        help="backend plugins, comma-separated (default: record)",
    )
    p.add_argument(
        "--config",
        metavar="FILE|NAME",
        help="robot profile or run preset: a YAML file, or a bundled profile's name (e.g. servo_head)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("convodrive-out"),
        metavar="DIR",
        help="output folder (default: ./convodrive-out)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed: the same seed gives the same motion (default: 0)")
    p.add_argument(
        "--motion",
        type=Path,
        metavar="FILE",
        help="motion file for the replay generator (.npz, .bvh or Live Link .csv)",
    )
    p.add_argument(
        "-G",
        "--generator-option",
        type=key_value,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="generator option, e.g. -G expressiveness=1.5",
    )
    p.add_argument(
        "-B",
        "--backend-option",
        type=backend_key_value,
        action="append",
        default=[],
        metavar="BACKEND.KEY=VALUE",
        help="backend option, e.g. -B render.camera=face",
    )


def plugin_options(args: argparse.Namespace) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """Generator options, and backend options by backend name, from ``add_motion_options``."""
    gen_options = dict(args.generator_option)
    if args.motion is not None:
        if args.generator != "replay":
            raise UserError(f"--motion is for the replay generator (this run's generator is {args.generator})")
        gen_options["motion"] = str(args.motion)
    backend_options: dict[str, dict[str, Any]] = {}
    for backend, key, value in args.backend_option:
        backend_options.setdefault(backend, {})[key] = value
    return gen_options, backend_options
