"""A rich progress bar for long offline runs, shown only on an interactive terminal."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

ProgressCallback = Callable[..., None]
"""``(done, total)``, or ``(done, total, label)`` to say what is being counted now."""


@contextlib.contextmanager
def frame_progress(label: str, enabled: bool = True) -> Iterator[ProgressCallback | None]:
    if not (enabled and sys.stderr.isatty()):
        yield None
        return
    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        transient=True,
        refresh_per_second=8,
    )
    task = progress.add_task(label, total=None)

    def update(done: int, total: int, label: str | None = None) -> None:
        progress.update(task, completed=done, total=total or None, **({"description": label} if label else {}))

    with progress:
        yield update


def drain_progress(progress: ProgressCallback | None, command: str) -> Callable[[int, int, list[str]], None]:
    """After the clock ends, backends may still be writing (videos lag a real-time run): show that
    work on the bar, or, with no bar (not a terminal), say it once when there is much left."""
    said = False

    def update(done: int, total: int, names: list[str]) -> None:
        nonlocal said
        label = f"finishing {', '.join(names)}"
        if progress is not None:
            progress(done, total, label)
        elif not said and total - done >= 30:
            said = True
            sys.stderr.write(f"{command}: {label} ({total - done} frames still to write)\n")
            sys.stderr.flush()

    return update
