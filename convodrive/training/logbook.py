"""The metrics log of a run: ``metrics.csv`` (long format, appended across resumptions) and
TensorBoard event files when ``tensorboard`` is installed."""

from __future__ import annotations

import csv
import importlib.util
import time
from pathlib import Path
from typing import Any

CSV_FIELDS = ("step", "wall_s", "split", "name", "value")


class Logbook:
    def __init__(self, out: Path, enabled: bool = True) -> None:
        self.enabled = enabled
        self.started = time.monotonic()
        self.path = out / "metrics.csv"
        self._tb: Any = None
        if not enabled:
            return
        new = not self.path.exists()
        self._fh = open(self.path, "a", newline="", encoding="utf-8")
        self._csv = csv.writer(self._fh)
        if new:
            self._csv.writerow(CSV_FIELDS)
        if importlib.util.find_spec("tensorboard") is not None:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(log_dir=str(out / "tensorboard"))

    @property
    def tensorboard(self) -> bool:
        return self._tb is not None

    def log(self, step: int, split: str, figures: dict[str, float]) -> None:
        if not self.enabled:
            return
        wall = round(time.monotonic() - self.started, 3)
        for name, value in figures.items():
            self._csv.writerow((step, wall, split, name, f"{float(value):.6g}"))
            if self._tb is not None:
                self._tb.add_scalar(f"{split}/{name}", float(value), step)
        self._fh.flush()

    def close(self) -> None:
        if not self.enabled:
            return
        self._fh.close()
        if self._tb is not None:
            self._tb.close()
