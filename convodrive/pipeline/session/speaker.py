"""A speaker with no sound card: plays the ring at the pace of the monotonic clock.

It stands in for ``audio.live.Playback`` where there is no audio device (tests, benchmarks, an
agent whose voice goes out as a file or a stream) and knows exactly when each sample "left":
sample n leaves at ``start + n / rate + latency``. It keeps what it played, with those times,
so the audio–motion offset can be measured against it.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from convodrive.audio.live.ring import SampleRing

BLOCK_SECONDS = 0.01


class VirtualSpeaker:
    """``Playback``'s interface (``ring``, ``rate``, ``position_at``, ``played``, ``stopped``,
    ``drain``, ``close``, ``report``) over a thread that reads a 10 ms block every 10 ms."""

    def __init__(self, rate: int, ring_seconds: float, latency: float = 0.0, keep: bool = True) -> None:
        self.rate = int(rate)
        self.ring = SampleRing(int(ring_seconds * self.rate))
        self.latency = float(latency)
        self.block = max(1, int(round(self.rate * BLOCK_SECONDS)))
        self._t0: float | None = None
        self._keep: list[np.ndarray] | None = [] if keep else None
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="virtual-speaker", daemon=True)

    def start(self) -> None:
        self._t0 = time.monotonic() + self.latency
        self._thread.start()

    def _run(self) -> None:
        assert self._t0 is not None
        start = self._t0 - self.latency
        block = np.zeros(self.block, np.float32)
        n = 0
        while not self._halt.is_set():
            due = start + n * self.block / self.rate
            delay = due - time.monotonic()
            if delay > 0:
                self._halt.wait(delay)
            self.ring.read_into(block)
            if self._keep is not None:
                self._keep.append(block.copy())
            n += 1

    def position_at(self, mono: float) -> float | None:
        """Seconds of the ring that have left the speaker at monotonic time ``mono``."""
        return None if self._t0 is None else mono - self._t0

    def mono_of(self, position: float) -> float:
        """The monotonic time ring position ``position`` (seconds) leaves the speaker."""
        assert self._t0 is not None
        return self._t0 + position

    def played(self) -> int:
        return self.ring.read_pos

    def stopped(self) -> str | None:
        return None

    def drain(self, position: int, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.ring.read_pos < position:
            time.sleep(0.005)

    def samples(self) -> np.ndarray:
        """Everything played so far, from position 0."""
        parts = list(self._keep or [])
        return np.concatenate(parts) if parts else np.zeros(0, np.float32)

    def close(self) -> None:
        self._halt.set()
        if self._thread.ident is not None:
            self._thread.join(timeout=1.0)

    def report(self) -> dict[str, Any]:
        return {
            "device": "virtual",
            "sample_rate": self.rate,
            "block_ms": round(1000.0 * self.block / self.rate, 2),
            "output_latency_ms": round(1000.0 * self.latency, 2),
            "underruns": self.ring.underruns,
            "underrun_ms": round(1000.0 * self.ring.underrun_samples / self.rate, 1),
            "stalls": 0,
            "stopped": None,
        }
