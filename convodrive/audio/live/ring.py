"""A ring of samples between a PortAudio callback and a thread, never blocking either side.

One writer and one reader, each owning one counter; under the GIL an int assignment is atomic, so
neither side takes a lock the other could hold (a callback must never wait). Positions count
samples since the stream began, so they double as the stream's time line.

The two rings of a live run use it differently:

- playback: a thread writes the self voice ahead; the output callback reads. A read the writer
  has not filled is an *underrun*: the callback plays zeros and the read position still advances,
  so the time line stays true to the speaker; the late samples are skipped when they arrive.
- capture: the input callback writes; a thread reads. A write that finds the ring full is an
  *overrun*: the new samples are dropped and counted.
"""

from __future__ import annotations

import numpy as np


class SampleRing:
    """Mono float32 samples at absolute positions; ``capacity`` bounds how far writes run ahead."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("ring capacity must be at least 1 sample")
        self.capacity = int(capacity)
        self._buf = np.zeros(self.capacity, np.float32)
        self.write_pos = 0
        self.read_pos = 0
        self.overrun_samples = 0
        self.overruns = 0
        self.underrun_samples = 0
        self.underruns = 0

    def available(self) -> int:
        """Samples written and not yet read."""
        return max(self.write_pos - self.read_pos, 0)

    def space(self) -> int:
        return self.capacity - self.available()

    # -- writer side ----------------------------------------------------------------------------
    def write(self, samples: np.ndarray) -> int:
        """Write what fits; return how many samples of ``samples`` were used (written or skipped
        because the reader already passed their position)."""
        data = np.asarray(samples, np.float32).reshape(-1)
        used = 0
        behind = self.read_pos - self.write_pos
        if behind > 0:  # the reader played silence here already: these samples are too late
            used = min(behind, len(data))
            self.write_pos += used
            data = data[used:]
        n = min(len(data), self.space())
        if n:
            self._copy_in(self.write_pos, data[:n])
            self.write_pos += n
        return used + n

    def write_or_drop(self, samples: np.ndarray) -> None:
        """Write from a callback: whatever does not fit is dropped and counted as an overrun."""
        written = self.write(samples)
        if written < len(samples):
            self.overruns += 1
            self.overrun_samples += len(samples) - written

    def blank(self, start: int) -> None:
        """Silence what is written from position ``start`` (at least the read position) on: queued
        voice an interruption drops. The reader may be mid-block; what it has taken stays."""
        stop = self.write_pos
        start = max(int(start), self.read_pos)
        if stop > start:
            self._buf[np.arange(start, stop) % self.capacity] = 0.0

    def _copy_in(self, pos: int, data: np.ndarray) -> None:
        start = pos % self.capacity
        first = min(len(data), self.capacity - start)
        self._buf[start : start + first] = data[:first]
        self._buf[: len(data) - first] = data[first:]

    # -- reader side ----------------------------------------------------------------------------
    def read(self, n: int) -> np.ndarray:
        """Up to ``n`` written samples (fewer if fewer are there); the reader waits for the rest."""
        n = min(int(n), self.available())
        out = self._copy_out(self.read_pos, n)
        self.read_pos += n
        return out

    def read_into(self, out: np.ndarray) -> int:
        """Fill ``out`` from the ring, zeros where nothing was written yet; always advances by
        ``len(out)``. Returns the number of missing samples (an underrun when > 0)."""
        n = len(out)
        have = min(n, self.available())
        out[:have] = self._copy_out(self.read_pos, have)
        out[have:] = 0.0
        self.read_pos += n
        missing = n - have
        if missing:
            self.underruns += 1
            self.underrun_samples += missing
        return missing

    def _copy_out(self, pos: int, n: int) -> np.ndarray:
        start = pos % self.capacity
        first = min(n, self.capacity - start)
        return np.concatenate([self._buf[start : start + first], self._buf[: n - first]])
