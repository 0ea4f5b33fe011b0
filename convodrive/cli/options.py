"""Argument types shared by subcommands: each turns bad input into a one-line argparse error."""

from __future__ import annotations

import argparse
from typing import Any

import yaml

from convodrive.audio.source import ChannelMap


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


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a number of at least 1, got {value}")
    return value


def key_value(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` with VALUE read as YAML, so numbers and booleans keep their types."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    return key.strip(), value


def backend_key_value(text: str) -> tuple[str, str, Any]:
    """``BACKEND.KEY=VALUE``, e.g. ``render.camera=face``."""
    key, value = key_value(text)
    backend, dot, option = key.partition(".")
    if not dot or not backend or not option:
        raise argparse.ArgumentTypeError(f"expected BACKEND.KEY=VALUE (e.g. render.camera=face), got {text!r}")
    return backend, option, value
