"""A restricted unpickler for data sets shipped as pickles (SHOW / TalkSHOW / ProbTalk ``.pkl``).

Unpickling runs whatever callables a file names, so a careless ``pickle.load`` of a downloaded
file can run any code. This one resolves only what data needs: NumPy arrays, dtypes and scalars,
and ``collections.OrderedDict``; plain containers, numbers and strings need no lookup at all.
Anything else is refused with one line naming the file and the callable it asked for.

Containers are bounded too: a few hundred bytes can build a list that holds itself, or shared
references that expand to 2^60 paths for any code walking them (``drop_skipped``, ``np.asarray``).
``load_pickle`` measures the structure once with a memo and refuses one nested deeper than
``MAX_DEPTH`` or holding more than ``MAX_ITEMS`` items once expanded.

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


MAX_DEPTH = 32
"""Containers nested deeper than this are refused: SHOW's pickles nest two or three levels."""
MAX_ITEMS = 1_000_000
"""Items (counting shared references once per path) above this are refused: SHOW's pickles hold
a few dozen entries, their bulk is in arrays, which count one each."""


class _Refused(pickle.UnpicklingError):
    """The pickle named a callable outside the allowed set."""


class _Unbounded(Exception):
    """The pickle's containers cannot be walked in bounded time and memory."""


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
        value = _Restricted(io.BytesIO(data)).load()
    except _Refused as exc:
        raise InputFileError(
            path, f"refused: the pickle asks for {exc}; only arrays and plain containers are read"
        ) from None
    except pickle.UnpicklingError as exc:
        raise InputFileError(path, f"not a readable pickle ({exc})") from None
    except (EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError, MemoryError) as exc:
        raise InputFileError(path, f"truncated or corrupt pickle ({exc.__class__.__name__})") from None
    problem = _unbounded(value)
    if problem:
        raise InputFileError(path, f"refused: {problem}")
    return value


def _unbounded(value: Any) -> str | None:
    """Why ``value`` cannot be walked path by path in bounded time, or None: each container is
    measured once (memo by id), so shared references cost nothing here."""
    expanded: dict[int, int] = {}
    open_now: set[int] = set()

    def size(v: Any, depth: int) -> int:
        if not isinstance(v, (dict, list, tuple)):
            return 1
        key = id(v)
        if key in expanded:
            return expanded[key]
        if key in open_now:
            raise _Unbounded("a container holds itself")
        if depth > MAX_DEPTH:
            raise _Unbounded(f"containers nested deeper than {MAX_DEPTH}")
        open_now.add(key)
        items = v.values() if isinstance(v, dict) else v
        total = 1
        for item in items:
            total += size(item, depth + 1)
            if total > MAX_ITEMS:
                raise _Unbounded(f"more than {MAX_ITEMS} items once shared references are expanded")
        open_now.discard(key)
        expanded[key] = total
        return total

    try:
        size(value, 0)
    except _Unbounded as exc:
        return str(exc)
    return None


def drop_skipped(value: Any) -> tuple[Any, list[str]]:
    """``value`` (bounded by ``load_pickle``) without the ``Skipped`` placeholders (dict entries and list items), and the keys dropped."""
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
