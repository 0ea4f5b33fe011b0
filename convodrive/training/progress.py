"""What a training run shows while it runs: a progress bar on a terminal, else one line per validation."""

from __future__ import annotations

import sys
from typing import Any


class Progress:
    """A rich progress bar on a terminal; otherwise one line per validation on stderr."""

    def __init__(self, label: str, total: int, done: int, enabled: bool) -> None:
        self.enabled = enabled
        self.bar: Any = None
        if enabled and sys.stderr.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("loss {task.fields[loss]}"),
                TimeRemainingColumn(),
                transient=True,
            )
            self.task = self.bar.add_task(label, total=total, completed=done, loss="-")
            self.bar.start()
        self.total = total

    def update(self, step: int, loss: float) -> None:
        if self.bar is not None:
            self.bar.update(self.task, completed=step, loss=f"{loss:.4g}")

    def note(self, step: int, figures: dict[str, float]) -> None:
        if not self.enabled or not figures:
            return
        text = " ".join(f"{k} {v:.4g}" for k, v in figures.items())
        line = f"step {step}/{self.total}: val {text}"
        if self.bar is not None:
            self.bar.console.print(line)
        else:
            print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
