"""Calibrated servo ranges back into a robot profile, as a line-level edit that keeps the file's
comments and layout (``convodrive servo calibrate``, for either bus: one ``joints`` format)."""

from __future__ import annotations

import re
from pathlib import Path

from convodrive.plumbing.errors import InputFileError
from convodrive.plumbing.safe_yaml import parse_yaml

_KEY = re.compile(r"^(\s*)([A-Za-z_][\w-]*)\s*:(.*)$")


def set_joint_limits(text: str, backend: str, limits: dict[str, tuple[int, int]], path: Path) -> str:
    """Rewrite ``min_tick``/``max_tick`` of ``backends.<backend>.joints.<name>`` in place.

    A line-level edit, so comments, order and formatting of the rest of the profile survive
    (a YAML round trip would drop them). The result is parsed back to check every value landed.
    """
    lines = text.splitlines(keepends=True)
    stack: list[tuple[int, str]] = []
    spans: dict[str, list[int]] = {}
    for i, line in enumerate(lines):
        m = _KEY.match(line)
        if not m or line.lstrip().startswith("#"):
            continue
        indent = len(m.group(1))
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, m.group(2)))
        keys = [k for _, k in stack]
        if keys[:3] == ["backends", backend, "joints"] and len(keys) >= 4:
            spans.setdefault(keys[3], []).append(i)
    for name, (lo, hi) in limits.items():
        if name not in spans:
            raise InputFileError(path, f"backends.{backend}.joints.{name}: not found")
        for key, value in (("min_tick", lo), ("max_tick", hi)):
            pattern = re.compile(rf"(\b{key}\s*:\s*)-?\d+")
            hit = [i for i in spans[name] if pattern.search(lines[i])]
            if hit:
                lines[hit[0]] = pattern.sub(rf"\g<1>{value}", lines[hit[0]], count=1)
            elif "}" in lines[spans[name][0]]:  # flow mapping on one line: add before the brace
                head = spans[name][0]
                brace = lines[head].rfind("}")
                lines[head] = f"{lines[head][:brace]}, {key}: {value}{lines[head][brace:]}"
            else:
                head = spans[name][0]
                indent = len(lines[head]) - len(lines[head].lstrip()) + 2
                lines.insert(head + 1, " " * indent + f"{key}: {value}\n")
                spans = {k: [j + (j > head) for j in v] for k, v in spans.items()}
    result = "".join(lines)
    parsed = parse_yaml(result, path)
    for name, (lo, hi) in limits.items():
        got = parsed["backends"][backend]["joints"][name]
        if (got.get("min_tick"), got.get("max_tick")) != (lo, hi):
            raise InputFileError(path, f"backends.{backend}.joints.{name}: could not update the limits in place")
    return result
