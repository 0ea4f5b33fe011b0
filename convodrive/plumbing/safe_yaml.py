"""YAML from users, loaded safely: the one loader for profiles, run configs and option values.

``yaml.safe_load`` builds no objects, but it still lets a small file do harm: a few lines of
aliases ("billion laughs") expand to billions of nodes when anything walks or prints the result,
5,000 nested brackets overflow the recursion limit, and a repeated key silently replaces the
first. This loader refuses all three with one line naming the file and the line, and keeps
PyYAML's own reason for a syntax error.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from convodrive.plumbing.errors import InputFileError, os_reason
from convodrive.plumbing.text import clip_value

MAX_ALIASES = 100
"""Aliases (``*name``) a document may use; real profiles use a handful."""
MAX_NODES = 100_000
"""Nodes a document may hold once every alias is expanded."""
MAX_DEPTH = 64
"""How deeply collections may nest."""
MAX_BYTES = 4 * 1024 * 1024
"""Largest YAML file read (profiles and configs are a few kB)."""

_MERGE_TAG = "tag:yaml.org,2002:merge"


class _Refused(yaml.MarkedYAMLError):
    """A document this loader will not build (not a syntax error)."""


class _GuardedLoader(yaml.SafeLoader):
    """SafeLoader with limits on aliases, depth and expanded size, and no duplicate keys."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._aliases = 0
        self._depth = 0

    def compose_node(self, parent: Node | None, index: Any) -> Node:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise _Refused(None, None, f"more than {MAX_ALIASES} aliases (*name)", event.start_mark)
            return super().compose_node(parent, index)
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise _Refused(None, None, f"nested deeper than {MAX_DEPTH} levels", event.start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def get_single_node(self) -> Node | None:
        node = super().get_single_node()
        if node is not None and self._aliases:
            _check_expanded_size(node)
        return node

    def construct_mapping(self, node: Node, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, MappingNode):
            seen: dict[tuple[str, str], Node] = {}
            for key_node, _ in node.value:
                if isinstance(key_node, ScalarNode) and key_node.tag != _MERGE_TAG:
                    key = (key_node.tag, key_node.value)
                    if key in seen:
                        line = seen[key].start_mark.line + 1
                        raise _Refused(
                            None,
                            None,
                            f"duplicate key {clip_value(key_node.value)} (first at line {line})",
                            key_node.start_mark,
                        )
                    seen[key] = key_node
            for key_node, value_node in node.value:
                if isinstance(key_node, ScalarNode) and isinstance(value_node, ScalarNode):
                    _check_int(value_node, clip_value(key_node.value, 40).strip("'") + ": ")
        return super().construct_mapping(node, deep=deep)

    def construct_yaml_int(self, node: ScalarNode) -> int:
        _check_int(node, "")
        return super().construct_yaml_int(node)


_GuardedLoader.add_constructor("tag:yaml.org,2002:int", _GuardedLoader.construct_yaml_int)


def _check_int(node: ScalarNode, where: str) -> None:
    """Refuse an integer too long for Python to convert (its int-string limit): one line, not the
    ValueError PyYAML would raise."""
    if node.tag != "tag:yaml.org,2002:int":
        return
    digits = sum(c.isalnum() for c in node.value)
    limit = sys.get_int_max_str_digits() or digits + 1
    if digits > limit:
        raise _Refused(None, None, f"{where}an integer of {digits} digits is too long", node.start_mark)


def _check_expanded_size(root: Node) -> None:
    """Refuse a node graph that expands to more than MAX_NODES nodes (or refers to itself)."""
    size: dict[int, int] = {}
    stack: list[tuple[Node, bool]] = [(root, False)]
    open_nodes: set[int] = set()
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        children = _children(node)
        if children_done:
            open_nodes.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in children)
            if size[key] > MAX_NODES:
                raise _Refused(None, None, f"aliases expand to more than {MAX_NODES:,} values", node.start_mark)
            continue
        if key in size:
            continue
        if key in open_nodes:
            raise _Refused(None, None, "an alias refers to the collection that contains it", node.start_mark)
        open_nodes.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in children if id(c) not in size)


def _children(node: Node) -> list[Node]:
    if isinstance(node, SequenceNode):
        return list(node.value)
    if isinstance(node, MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def parse_yaml(text: str, source: str | os.PathLike[str]) -> Any:
    """The document in ``text``; ``InputFileError(source, ...)`` for a syntax error or a refusal."""
    loader = _GuardedLoader(text)
    try:
        return loader.get_single_data()
    except _Refused as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}: " if mark is not None else ""
        raise InputFileError(source, f"{where}{exc.problem}") from None
    except yaml.YAMLError as exc:
        reason = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputFileError(source, f"not valid YAML{_at_line(exc)}: {reason}") from None
    except RecursionError:  # a guard above should have stopped it first
        raise InputFileError(source, f"nested deeper than {MAX_DEPTH} levels") from None
    finally:
        loader.dispose()


def _at_line(exc: yaml.YAMLError) -> str:
    mark = getattr(exc, "problem_mark", None)
    return f" at line {mark.line + 1}" if mark is not None else ""


def load_yaml_file(path: str | os.PathLike[str]) -> Any:
    """Read and parse a user's YAML file; every failure is one ``InputFileError`` line."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise InputFileError(path, "no such file") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a folder, not a YAML file") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({os_reason(exc)})") from None
    if len(raw) > MAX_BYTES:
        raise InputFileError(path, f"larger than {MAX_BYTES // (1024 * 1024)} MiB; not a config file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputFileError(path, f"not UTF-8 text (byte {exc.start})") from None
    return parse_yaml(text, path)


_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def number_text(value: Any) -> Any:
    """``"1e9"`` as the number 1e9: YAML 1.1 reads an exponent without a dot as text, where a person
    means a number. Anything else is returned as it is."""
    if isinstance(value, str) and _NUMBER.fullmatch(value.strip()):
        return float(value)
    return value


def parse_scalar(text: str) -> Any:
    """A command-line value read as YAML (``3`` is a number, ``true`` a boolean); text that is not
    valid YAML stays text."""
    if not text.strip():
        return ""
    try:
        return parse_yaml(text, "value")
    except InputFileError:
        return text
