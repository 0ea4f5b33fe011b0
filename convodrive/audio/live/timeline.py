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

    def append(self, samples: np.ndarray) -> None:
        data = np.asarray(samples, np.float32).reshape(-1)
        if not len(data):
            return
        with self._lock:
            self._parts.append(data.copy())
            self.end += len(data)

    def fill_to(self, position: int) -> int:
        """Append silence up to ``position``; return how many samples were filled."""
        missing = int(position) - self.end
        if missing > 0:
            self.append(np.zeros(missing, np.float32))
        return max(missing, 0)

    def blank(self, start: int) -> None:
        """Silence the samples from position ``start`` on that are not yet taken: what an
        interruption must not let the generator hear (a voice that will not be played)."""
        with self._lock:
            pos = self.taken
            for part in self._parts:
                lo = max(start - pos, 0)
                if lo < len(part):
                    part[lo:] = 0.0
                pos += len(part)

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
