"""Text for one-line messages: a user's value is shown short, on one line, never expanded."""

from __future__ import annotations

from typing import Any

MAX_VALUE_CHARS = 60


def clip_value(value: Any, limit: int = MAX_VALUE_CHARS) -> str:
    """``repr(value)`` on one line, cut to ``limit`` characters (an alias bomb stays one line)."""
    try:
        text = repr(value) if not isinstance(value, str) else repr(value[: limit + 1])
    except Exception:  # a value whose repr fails is still reported
        text = f"<{type(value).__name__}>"
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"
