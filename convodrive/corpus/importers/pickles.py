"""A restricted unpickler for data sets shipped as pickles (SHOW / TalkSHOW / ProbTalk ``.pkl``).

Unpickling runs whatever callables a file names, so a careless ``pickle.load`` of a downloaded
file can run any code. This one resolves only what data needs: NumPy arrays, dtypes and scalars,
and ``collections.OrderedDict``; plain containers, numbers and strings need no lookup at all.
Anything else is refused with one line naming the file and the callable it asked for.

One exception, because SHOW's files need it: they keep their fitting losses as torch tensors
(``losses_to_log``). A name from ``torch`` resolves to ``Skipped``, an inert placeholder that
records nothing and runs nothing, so such values are dropped without importing torch.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any

from convodrive.plumbing.errors import InputFileError

_NUMPY = {
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("collections", "OrderedDict"),
}


class Skipped:
    """Stands in for a value the unpickler will not build (a torch tensor); accepts and keeps nothing."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        pass

    def __repr__(self) -> str:
        return "<skipped>"


class _Refused(pickle.UnpicklingError):
    """The pickle named a callable outside the allowed set."""


class _Restricted(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _NUMPY:
            return super().find_class(module, name)
        if module == "torch" or module.startswith("torch."):
            return Skipped
        raise _Refused(f"{module}.{name}")

    def persistent_load(self, pid: Any) -> Any:
        return Skipped()


def load_pickle(path: Path) -> Any:
    """The object in ``path``, built from arrays and plain containers only; torch values become
    ``Skipped``. A pickle naming anything else is an ``InputFileError``."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({exc.strerror})") from None
    try:
        return _Restricted(io.BytesIO(data)).load()
    except _Refused as exc:
        raise InputFileError(
            path, f"refused: the pickle asks for {exc}; only arrays and plain containers are read"
        ) from None
    except pickle.UnpicklingError as exc:
        raise InputFileError(path, f"not a readable pickle ({exc})") from None
    except (EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError, MemoryError) as exc:
        raise InputFileError(path, f"truncated or corrupt pickle ({exc.__class__.__name__})") from None


def drop_skipped(value: Any) -> tuple[Any, list[str]]:
    """``value`` without the ``Skipped`` placeholders (dict entries and list items), and the keys dropped."""
    dropped: list[str] = []

    def walk(v: Any, where: str) -> Any:
        if isinstance(v, dict):
            out = {}
            for k, item in v.items():
                cleaned = walk(item, f"{where}{k}.")
                if cleaned is _DROP:
                    dropped.append(f"{where}{k}")
                else:
                    out[k] = cleaned
            return out
        if isinstance(v, (list, tuple)):
            items = [walk(item, where) for item in v]
            return type(v)(i for i in items if i is not _DROP)
        if isinstance(v, Skipped):
            return _DROP
        return v

    cleaned = walk(value, "")
    return (None if cleaned is _DROP else cleaned), dropped


_DROP = object()
