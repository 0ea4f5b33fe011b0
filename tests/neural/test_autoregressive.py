"""Nucleus sampling and the KV cache of the autoregressive loop, in NumPy."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.neural.autoregressive import KVCache, sample_tokens, softmax, top_p


def test_top_p_keeps_the_nucleus_only() -> None:
    logits = np.log(np.array([[0.5, 0.3, 0.15, 0.05]]))
    seen = {int(top_p(logits, 0.75, np.array([u]))[0]) for u in np.linspace(0, 0.999, 200)}
    assert seen == {0, 1}  # 0.5 + 0.3 reach 0.75; the tail is never drawn
    assert {int(top_p(logits, 0.1, np.array([u]))[0]) for u in (0.0, 0.5, 0.99)} == {0}  # argmax
    assert {int(top_p(logits, 1.0, np.array([u]))[0]) for u in np.linspace(0, 0.999, 400)} == {0, 1, 2, 3}


def test_top_p_draws_follow_the_renormalised_nucleus() -> None:
    rng = np.random.default_rng(0)
    logits = np.log(np.array([0.4, 0.3, 0.2, 0.1]))[None].repeat(20000, axis=0)
    draws = top_p(logits, 0.85, rng.random(20000))
    freq = np.bincount(draws, minlength=4) / len(draws)
    np.testing.assert_allclose(freq, [0.4 / 0.9, 0.3 / 0.9, 0.2 / 0.9, 0.0], atol=0.015)
    with pytest.raises(ValueError):
        top_p(logits[:1], 0.0, np.zeros(1))


def test_softmax_is_stable() -> None:
    np.testing.assert_allclose(softmax(np.array([[1000.0, 1000.0]])), [[0.5, 0.5]])


def test_the_cache_keeps_the_band_and_the_loop_matches_a_full_rerun() -> None:
    """A toy step graph whose logits sum the cached keys of the last band-1 positions equals a
    full re-run over the same window of history, and the cache never grows past band - 1."""
    band, vocab = 5, 7
    table = np.random.default_rng(1).standard_normal((vocab + 1, vocab))

    def step(token, position, keys, values):  # keys: (1, B, 1, P, vocab)
        new = table[token[:, 0]][None, :, None, None, :]
        keys = np.concatenate([keys, new], axis=3)
        return keys.sum(axis=3)[0, :, 0], keys, keys

    cache = KVCache.empty(1, 2, 1, vocab, band, start_token=vocab)
    rngs = [np.random.default_rng(i) for i in range(2)]
    tokens = sample_tokens(step, cache, 12, 0.9, rngs)
    assert cache.keys.shape[3] == band - 1 and cache.position == 12
    history = np.concatenate([np.full((2, 1), vocab), tokens], axis=1)
    rngs = [np.random.default_rng(i) for i in range(2)]
    for i in range(12):
        logits = table[history[:, max(0, i - band + 1) : i + 1]].sum(axis=1)
        expected = top_p(logits, 0.9, np.array([r.random() for r in rngs]))
        np.testing.assert_array_equal(tokens[:, i], expected)


def test_temperature_sharpens_or_flattens_the_draws() -> None:
    """Logits divided by the temperature: near 0 the argmax only, above 1 the tail more often,
    and at 1 the draws of no temperature at all."""
    vocab = 4
    logits = np.log(np.array([0.55, 0.25, 0.15, 0.05]))

    def draws(temperature: float | None) -> np.ndarray:
        def step(token, position, keys, values):
            return np.repeat(logits[None], len(token), axis=0), keys, values

        empty = np.zeros((1, 4000, 1, 0, 1), np.float32)
        cache = KVCache(empty, empty, band=2, token=np.zeros((4000, 1), np.int64))
        rngs = [np.random.default_rng(i) for i in range(4000)]
        extra = {} if temperature is None else {"temperature": temperature}
        return sample_tokens(step, cache, 1, 1.0, rngs, **extra)[:, 0]

    np.testing.assert_array_equal(draws(1.0), draws(None))
    assert set(draws(0.05).tolist()) == {0}
    tail = {t: float(np.mean(draws(t) >= 2)) for t in (1.0, 2.0)}
    assert abs(tail[1.0] - 0.2) < 0.03 and tail[2.0] > tail[1.0] + 0.05
    assert np.bincount(draws(2.0), minlength=vocab)[3] > np.bincount(draws(1.0), minlength=vocab)[3]
