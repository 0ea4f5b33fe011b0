"""Argument types shared by subcommands: each turns bad input into a one-line argparse error."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from convodrive.audio.source import ChannelMap
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


def backend_key_value(text: str) -> tuple[str, str, Any]:
    """``BACKEND.KEY=VALUE``, e.g. ``render.camera=face``."""
    key, value = key_value(text)
    backend, dot, option = key.partition(".")
    if not dot or not backend or not option:
        raise argparse.ArgumentTypeError(
            f"expected BACKEND.KEY=VALUE (e.g. render.camera=face), got {clip_value(text)}"
        )
    return backend, option, value
