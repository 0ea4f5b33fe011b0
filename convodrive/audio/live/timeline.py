"""One voice at the analysis rate, as a time line: samples at absolute positions, appended as they
become known and taken in order by the generator's side."""

from __future__ import annotations

import collections
import threading

import numpy as np


class Timeline:
    """Appended by one thread, taken in order by another."""

    def __init__(self) -> None:
        self._parts: collections.deque[np.ndarray] = collections.deque()
        self._lock = threading.Lock()
        self.taken = 0
        """Position of the first sample not yet taken."""
        self.end = 0
        """Position one past the last sample appended."""
        self._muted: list[tuple[int, int]] = []
        """Ranges ``blank`` silenced beyond ``end``: samples appended there come in silent."""

    def append(self, samples: np.ndarray) -> None:
        data = np.asarray(samples, np.float32).reshape(-1)
        if not len(data):
            return
        with self._lock:
            data = data.copy()
            for lo, hi in self._muted:
                data[max(lo - self.end, 0) : max(hi - self.end, 0)] = 0.0
            self.end += len(data)
            self._parts.append(data)
            self._muted = [(lo, hi) for lo, hi in self._muted if hi > self.end]

    def fill_to(self, position: int) -> int:
        """Append silence up to ``position``; return how many samples were filled."""
        missing = int(position) - self.end
        if missing > 0:
            self.append(np.zeros(missing, np.float32))
        return max(missing, 0)

    def blank(self, start: int, stop: int | None = None) -> None:
        """Silence the samples from position ``start`` to ``stop`` (None: all appended so far)
        that are not yet taken, those appended later included: what an interruption must not
        let the generator hear (a voice that will not be played)."""
        with self._lock:
            stop = self.end if stop is None else int(stop)
            pos = self.taken
            for part in self._parts:
                lo, hi = max(start - pos, 0), min(stop - pos, len(part))
                if lo < hi:
                    part[lo:hi] = 0.0
                pos += len(part)
            if stop > max(start, self.end):
                self._muted.append((max(int(start), self.end), stop))

    def take(self, stop: int) -> np.ndarray:
        """Remove and return the samples from ``taken`` up to ``stop`` (clipped to ``end``)."""
        with self._lock:
            n = max(min(int(stop), self.end) - self.taken, 0)
            out = np.zeros(n, np.float32)
            filled = 0
            while filled < n:
                part = self._parts[0]
                k = min(len(part), n - filled)
                out[filled : filled + k] = part[:k]
                filled += k
                if k == len(part):
                    self._parts.popleft()
                else:
                    self._parts[0] = part[k:]
            self.taken += n
            return out
