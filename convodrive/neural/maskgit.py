"""MaskGIT decoding in NumPy: the runtime's sampling loop around a graph that scores all tokens.

A window's tokens start masked. Each of T passes asks the graph for every token's logits, draws a
code for each masked token, keeps the most confident draws and masks the rest again, fewer each
pass along the cosine schedule (Chang et al., 2022; ProbTalk's predictor). Confidence is the
draw's log-probability plus Gumbel noise that anneals to zero, so early passes keep a varied set
of tokens and the last pass commits everything.

Each row of the batch (one take) draws its random numbers from its own generator, in a fixed
order (``draw_uniforms``), so a take is the same whether it runs alone or beside others, and the
torch reference (``convodrive.models.probtalk_predictor.maskgit_sample``) reproduces it from the same draws.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

CHOICE_TEMPERATURE = 4.5
"""Scale of the Gumbel noise on confidences at the first pass (the reference's value)."""


def remask_count(length: int, step: int, iterations: int) -> int:
    """Tokens masked again after pass ``step`` (0-based) of ``iterations``: floor(N cos(pi/2 (t+1)/T))."""
    return int(math.floor(length * math.cos(math.pi / 2 * (step + 1) / iterations)))


def draw_uniforms(rngs: Sequence[np.random.Generator], iterations: int, length: int) -> np.ndarray:
    """(iterations, 2, takes, length) uniform draws in [0, 1): per pass, per take, the sampling
    draws then the Gumbel draws, each take from its own generator in pass order."""
    out = np.empty((iterations, 2, len(rngs), length))
    for t in range(iterations):
        for b, rng in enumerate(rngs):
            out[t, 0, b] = rng.random(length)
            out[t, 1, b] = rng.random(length)
    return out


def log_softmax(logits: np.ndarray) -> np.ndarray:
    z = logits - logits.max(axis=-1, keepdims=True)
    return z - np.log(np.exp(z).sum(axis=-1, keepdims=True))


def maskgit_sample(
    logits_fn: Callable[[np.ndarray], np.ndarray],
    length: int,
    codes: int,
    iterations: int,
    rngs: Sequence[np.random.Generator],
    temperature: float | np.ndarray = 1.0,
    choice_temperature: float = CHOICE_TEMPERATURE,
) -> np.ndarray:
    """(takes, length) int64 codes. ``logits_fn`` maps (takes, length) token ids, ``codes`` where a
    token is still masked, to (takes, length, codes) logits. ``temperature``: one for every take, or
    one per take ((takes,))."""
    temperature = np.asarray(temperature, np.float64)
    if iterations < 1 or np.any(temperature <= 0) or temperature.shape not in ((), (len(rngs),)):
        raise ValueError(
            f"iterations must be >= 1 and temperature > 0 (one, or one per take), got {iterations}, {temperature}"
        )
    temperature = temperature.reshape(-1, 1, 1)
    uniforms = draw_uniforms(rngs, iterations, length)
    mask_id = codes
    tokens = np.full((len(rngs), length), mask_id, np.int64)
    for t in range(iterations):
        unknown = tokens == mask_id
        if not unknown.any():
            break
        logp = log_softmax(np.asarray(logits_fn(tokens), np.float64) / temperature)
        cdf = np.cumsum(np.exp(logp), axis=-1)
        drawn = (cdf < uniforms[t, 0, :, :, None] * cdf[..., -1:]).sum(axis=-1)
        sampled = np.where(unknown, np.minimum(drawn, codes - 1), tokens)
        confidence = np.take_along_axis(logp, sampled[..., None], axis=-1)[..., 0]
        progress = (t + 1) / iterations
        gumbel = -np.log(-np.log(np.clip(uniforms[t, 1], 1e-20, 1 - 1e-12)))
        confidence = np.where(unknown, confidence + choice_temperature * (1 - progress) * gumbel, np.inf)
        remask = remask_count(length, t, iterations)
        tokens = sampled
        for b in range(len(rngs)):
            count = min(remask, int(unknown[b].sum()) - 1)
            if count > 0:
                tokens[b, np.argsort(confidence[b], kind="stable")[:count]] = mask_id
    return tokens
