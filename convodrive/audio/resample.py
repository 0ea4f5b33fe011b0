"""Streaming polyphase resampling: blocks of any size in, the same samples as resampling at once out.

``resample_poly`` filters a whole signal with zeros beyond both ends. Run on a window that starts
at a multiple of ``down`` input samples and carries ``context`` samples on each side (at least the
filter's half-length), it gives exactly the output samples of the whole-signal call for the
window's middle. So a stream keeps ``context`` samples of history, holds back ``context`` samples
of look-ahead (a latency of ``context / rate``, about 1 ms at 44.1 kHz to 16 kHz), and emits the
middle: the joined output equals resampling everything at once, whatever the block sizes.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from convodrive.plumbing.lazy_import import scipy_signal


class StreamResampler:
    """Resamples ``(n,)`` or ``(n, channels)`` float32 blocks from ``in_rate`` to ``out_rate``."""

    def __init__(self, in_rate: int, out_rate: int, channels: int = 1) -> None:
        ratio = Fraction(int(out_rate), int(in_rate))
        self.up, self.down = ratio.numerator, ratio.denominator
        self.identity = ratio == 1
        # resample_poly's filter has 10 * max(up, down) taps each side at the upsampled rate.
        half = 10 * max(self.up, self.down) / self.up + 4
        self.context = 0 if self.identity else self.down * math.ceil(half / self.down)
        self.channels = channels
        self._history = np.zeros((self.context, channels), np.float32)
        self._pending = np.zeros((0, channels), np.float32)
        self._received = 0
        self._emitted = 0

    @property
    def latency_samples(self) -> int:
        """Input samples held back before their output can be computed."""
        return self.context

    def push(self, block: np.ndarray) -> np.ndarray:
        """Add input; return every output sample that is now final (same shape kind as ``block``)."""
        block = np.asarray(block, np.float32)
        flat = block.ndim == 1
        rows = block[:, None] if flat else block
        self._received += len(rows)
        if self.identity:
            self._emitted += len(rows)
            return block.copy()
        self._pending = np.concatenate([self._pending, rows])
        usable = (len(self._pending) - self.context) // self.down * self.down
        if usable <= 0:
            return self._shape(np.zeros((0, self.channels), np.float32), flat)
        window = np.concatenate([self._history, self._pending[: usable + self.context]])
        out = self._middle(window, usable * self.up // self.down)
        self._history = window[usable : usable + self.context]
        self._pending = self._pending[usable:]
        return self._shape(out, flat)

    def finish(self, flat: bool = True) -> np.ndarray:
        """The rest of the output, the end padded with zeros, as ``resample_poly`` does."""
        total = math.ceil(self._received * self.up / self.down)
        need = total - self._emitted
        if self.identity or need <= 0:
            return self._shape(np.zeros((0, self.channels), np.float32), flat)
        tail = np.zeros((self.context + self.down, self.channels), np.float32)
        window = np.concatenate([self._history, self._pending, tail])
        out = self._middle(window, need)
        self._pending = np.zeros((0, self.channels), np.float32)
        return self._shape(out, flat)

    def _middle(self, window: np.ndarray, count: int) -> np.ndarray:
        first = self.context * self.up // self.down
        out = scipy_signal().resample_poly(window, self.up, self.down, axis=0).astype(np.float32)[first : first + count]
        self._emitted += len(out)
        return out

    def _shape(self, rows: np.ndarray, flat: bool) -> np.ndarray:
        return rows[:, 0].copy() if flat and self.channels == 1 else rows
