"""Options of the procedural generator, from the CLI or YAML ``generator: {procedural: {...}}``."""

from __future__ import annotations

import dataclasses
from typing import Any

from convodrive.plumbing.errors import UserError


@dataclasses.dataclass(frozen=True)
class ProceduralOptions:
    expressiveness: float = 1.0
    """Amplitude of head, brow, body and gesture motion (0 = still face and body, 2 = animated)."""
    variability: float = 1.0
    """How much takes differ: random jitter of timing, amplitude and choice (0 = least)."""
    phones: bool = True
    """Recognise English phones with pocketsphinx for the visemes; False uses the spectral fallback
    only (any language, and about three times faster)."""
    gestures: bool = True
    """Beat gestures of the arms and hands on stressed syllables."""
    vad_on_db: float = -40.0
    vad_off_db: float = -48.0

    @classmethod
    def from_dict(cls, options: dict[str, Any] | None) -> ProceduralOptions:
        options = dict(options or {})
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(options) - set(fields))
        if unknown:
            raise UserError(f"generator procedural: unknown option {unknown[0]!r} (known: {', '.join(fields)})")
        values: dict[str, Any] = {}
        for name, value in options.items():
            kind = type(getattr(cls, name))
            if kind is bool:
                if not isinstance(value, bool):
                    raise UserError(f"generator procedural: option {name!r} must be true or false, got {value!r}")
            else:
                try:
                    value = float(value)
                except (TypeError, ValueError):
                    raise UserError(f"generator procedural: option {name!r} must be a number, got {value!r}") from None
            values[name] = value
        opts = cls(**values)
        for name in ("expressiveness", "variability"):
            if not 0.0 <= getattr(opts, name) <= 3.0:
                raise UserError(
                    f"generator procedural: option {name!r} must be between 0 and 3, got {getattr(opts, name)}"
                )
        if opts.vad_off_db > opts.vad_on_db:
            raise UserError("generator procedural: vad_off_db must not exceed vad_on_db")
        return opts
