"""Autoregressive token sampling in NumPy with a key-value cache passed through a step graph.

A step graph takes one input token, its position, its conditions and the self-attention keys and
values of the earlier positions, and returns the next token's logits and the cache with its own
position appended. ``KVCache`` keeps the last ``band - 1`` positions (the model's self-attention
reach), so each token costs one step however long the stream and memory stays constant; the
result equals re-running the whole prefix with the model's banded causal mask.

``top_p`` is nucleus sampling (Holtzman et al.): the smallest set of tokens whose probabilities
reach ``p``, renormalised. Each take (row) draws from its own generator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

StepFn = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
"""(token (B, 1), position (B, 1), past keys, past values) -> (logits (B, V), keys, values)."""


def softmax(logits: np.ndarray) -> np.ndarray:
    z = np.asarray(logits, np.float64)
    z = np.exp(z - z.max(axis=-1, keepdims=True))
    return z / z.sum(axis=-1, keepdims=True)


def top_p(logits: np.ndarray, p: float, uniforms: np.ndarray) -> np.ndarray:
    """(B,) int64 tokens drawn from the nucleus of mass ``p`` of each row of ``logits`` (B, V),
    by inverting the renormalised nucleus's distribution at ``uniforms`` (B,) in [0, 1)."""
    if not 0 < p <= 1:
        raise ValueError(f"top_p must be in (0, 1], got {p}")
    probs = softmax(logits)
    order = np.argsort(-probs, axis=-1, kind="stable")
    ranked = np.take_along_axis(probs, order, axis=-1)
    before = np.cumsum(ranked, axis=-1) - ranked
    ranked = np.where(before < p, ranked, 0.0)
    cdf = np.cumsum(ranked, axis=-1)
    pick = (cdf < uniforms[:, None] * cdf[:, -1:]).sum(axis=-1)
    pick = np.minimum(pick, (ranked > 0).sum(axis=-1) - 1)
    return np.take_along_axis(order, pick[:, None], axis=-1)[:, 0].astype(np.int64)


@dataclasses.dataclass
class KVCache:
    """The self-attention keys and values (layers, B, heads, P, dh) of the last P <= band - 1
    positions, the next position and the input token there (the last token drawn)."""

    keys: np.ndarray
    values: np.ndarray
    band: int
    position: int = 0
    token: np.ndarray | None = None

    @classmethod
    def empty(cls, layers: int, batch: int, heads: int, head_dim: int, band: int, start_token: int) -> KVCache:
        shape = (layers, batch, heads, 0, head_dim)
        token = np.full((batch, 1), start_token, np.int64)
        return cls(np.zeros(shape, np.float32), np.zeros(shape, np.float32), band, 0, token)

    def advance(self, keys: np.ndarray, values: np.ndarray, token: np.ndarray) -> None:
        """Take the step graph's cache (this position appended) and the token it drew."""
        keep = self.band - 1
        self.keys, self.values = keys[:, :, :, -keep:], values[:, :, :, -keep:]
        self.position += 1
        self.token = token.reshape(-1, 1).astype(np.int64)


def sample_tokens(
    step: StepFn,
    cache: KVCache,
    count: int,
    p: float,
    rngs: Sequence[np.random.Generator],
    temperature: float = 1.0,
) -> np.ndarray:
    """(B, count) int64 tokens continuing ``cache`` (which advances by ``count`` positions), each
    drawn from the nucleus of mass ``p`` of the logits divided by ``temperature``."""
    out = np.empty((len(rngs), count), np.int64)
    for i in range(count):
        assert cache.token is not None
        position = np.full((len(rngs), 1), cache.position, np.int64)
        logits, keys, values = step(cache.token, position, cache.keys, cache.values)
        uniforms = np.array([rng.random() for rng in rngs])
        token = top_p(np.asarray(logits) / temperature, p, uniforms)
        cache.advance(keys, values, token)
        out[:, i] = token
    return out
