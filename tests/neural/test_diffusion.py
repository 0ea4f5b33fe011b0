"""Diffusion sampling in NumPy: the cosine schedule, step spacing, DDIM that recovers x0 when the
network knows it, DPM-Solver++ nearer the ODE's own answer than DDIM in as many steps, stochastic DDIM (eta) on the forward process's marginals, guidance as one batch, a scale a channel from a model that takes it as an input, pinned known frames, takes independent of the batch."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.neural.diffusion import (
    consistency_sample,
    cosine_schedule,
    ddim_noise_scale,
    ddim_sample,
    ddim_step,
    ddim_timesteps,
    dpm_solver_sample,
    grid_timesteps,
    guided,
    log_snr,
    log_snr_timesteps,
    noised,
    scaled_by_input,
    stochastic_ddim_step,
)

ABAR = cosine_schedule(1000)


def test_cosine_schedule_runs_from_signal_to_noise() -> None:
    assert ABAR.shape == (1000,)
    assert np.all(np.diff(ABAR) < 0)
    assert ABAR[0] > 0.999 and ABAR[-1] < 1e-4
    # Nichol and Dhariwal's alpha_bar(t) = f(t) / f(0), f = cos^2((t/T + s)/(1 + s) pi/2), away from the clip
    t = 500
    f = lambda u: np.cos((u / 1000 + 0.008) / 1.008 * np.pi / 2) ** 2  # noqa: E731
    assert ABAR[t - 1] == pytest.approx(f(t) / f(0), rel=1e-9)


def test_step_spacing_starts_at_the_last_step() -> None:
    assert ddim_timesteps(1).tolist() == [999]
    assert ddim_timesteps(4).tolist() == [999, 749, 499, 249]
    assert ddim_timesteps(100)[:3].tolist() == [999, 989, 979] and ddim_timesteps(100)[-1] == 9
    assert len(ddim_timesteps(1000)) == 1000 and ddim_timesteps(1000)[-1] == 0
    assert grid_timesteps(4, 1000, 20).tolist() == [999, 759, 499, 239]
    assert grid_timesteps(1, 1000, 20).tolist() == [999]
    with pytest.raises(ValueError):
        ddim_timesteps(0)
    with pytest.raises(ValueError):
        grid_timesteps(51, 1000, 20)


def test_ddim_step_follows_the_deterministic_path() -> None:
    rng = np.random.default_rng(0)
    x0, eps = rng.standard_normal((2, 5, 3)), rng.standard_normal((2, 5, 3))
    x_t = noised(x0, eps, ABAR[700])
    np.testing.assert_allclose(ddim_step(x_t, x0, ABAR[700], ABAR[300]), noised(x0, eps, ABAR[300]), atol=1e-12)


@pytest.mark.parametrize("steps", [1, 2, 4, 10, 25, 100])
def test_ddim_recovers_x0_from_an_oracle(steps: int) -> None:
    target = np.random.default_rng(1).standard_normal((3, 8, 4)).astype(np.float32)
    noise = np.random.default_rng(2).standard_normal(target.shape).astype(np.float32)
    calls = []

    def oracle(x: np.ndarray, t: np.ndarray) -> np.ndarray:
        calls.append(int(t[0]))
        return target

    np.testing.assert_allclose(ddim_sample(oracle, noise, steps, ABAR), target)
    assert calls == ddim_timesteps(steps).tolist()


def test_ddim_with_a_network_that_only_denoises_partly() -> None:
    """Against the DDIM recursion written out: x0 = 0.5 x_t at every step."""
    noise = np.random.default_rng(3).standard_normal((1, 4, 2)).astype(np.float32)
    x = noise.astype(np.float64)
    times = ddim_timesteps(3)
    for i, t in enumerate(times):
        x0 = 0.5 * x
        if i + 1 < len(times):
            eps = (x - np.sqrt(ABAR[t]) * x0) / np.sqrt(1 - ABAR[t])
            x = np.sqrt(ABAR[times[i + 1]]) * x0 + np.sqrt(1 - ABAR[times[i + 1]]) * eps
    out = ddim_sample(lambda x, t: 0.5 * x, noise, 3, ABAR)
    np.testing.assert_allclose(out, x0, rtol=1e-5)


@pytest.mark.parametrize("spacing", [ddim_timesteps(6), log_snr_timesteps(6, ABAR)])
def test_dpm_solver_recovers_x0_from_an_oracle_calling_at_its_steps(spacing: np.ndarray) -> None:
    target = np.random.default_rng(1).standard_normal((3, 8, 4)).astype(np.float32)
    noise = np.random.default_rng(2).standard_normal(target.shape).astype(np.float32)
    calls: list[int] = []

    def oracle(x: np.ndarray, t: np.ndarray) -> np.ndarray:
        calls.append(int(t[0]))
        return target

    np.testing.assert_allclose(dpm_solver_sample(oracle, noise, spacing, ABAR), target, rtol=1e-6)
    assert calls == spacing.tolist()


def test_log_snr_spacing_is_even_from_where_the_signal_starts_down_to_step_0() -> None:
    times = log_snr_timesteps(8, ABAR)
    assert times[-1] == 0 and ABAR[times[0]] >= 1e-4 > ABAR[times[0] + 1]
    assert np.all(np.diff(times) < 0)
    gaps = np.diff(log_snr(ABAR[times]))
    assert gaps.max() - gaps.min() < 0.2 * gaps.mean()  # even, up to the nearest whole step
    assert log_snr_timesteps(1, ABAR).tolist() == [times[0]]
    with pytest.raises(ValueError, match="repeat"):
        log_snr_timesteps(60, ABAR)


def test_dpm_solver_follows_the_ode_closer_than_ddim() -> None:
    """Gaussian data (std 0.3 a dimension): the exact x0 predictor is linear and the ODE's answer is
    known in closed form (x_t over its marginal std stays constant), so each sampler's error is
    measured against the exact path, not against another sampler."""
    var = 0.3**2

    def exact_x0(x: np.ndarray, t: np.ndarray) -> np.ndarray:
        a = ABAR[t][:, None, None]
        return (np.sqrt(a) * var / (a * var + 1 - a) * x).astype(np.float32)

    noise = np.random.default_rng(0).standard_normal((4, 50, 3)).astype(np.float32)
    for steps in (8, 16):
        last = int(ddim_timesteps(steps)[-1])
        spread = lambda t: np.sqrt(ABAR[t] * var + 1 - ABAR[t])  # noqa: E731
        answer = exact_x0(noise * spread(last) / spread(999), np.array([last]))
        ddim_error = np.abs(ddim_sample(exact_x0, noise, steps, ABAR) - answer).max()
        dpm_error = np.abs(dpm_solver_sample(exact_x0, noise, ddim_timesteps(steps), ABAR) - answer).max()
        assert dpm_error < ddim_error / 3, (steps, dpm_error, ddim_error)
        assert dpm_error < 0.03 * np.abs(answer).max()


def test_guidance_batches_both_halves_in_one_call() -> None:
    calls = []

    def x0_fn(x: np.ndarray, t: np.ndarray) -> np.ndarray:
        calls.append(len(x))
        out = np.zeros_like(x)
        out[: len(x) // 2] = 3.0  # conditional rows
        out[len(x) // 2 :] = 1.0  # unconditional rows
        return out

    got = guided(x0_fn, 2.5)(np.zeros((4, 2, 1), np.float32), np.zeros(4, np.int64))
    assert calls == [8]
    np.testing.assert_allclose(got, 1.0 + 2.5 * (3.0 - 1.0))


def test_a_scale_a_channel_is_one_pass_a_distinct_scale_in_one_call() -> None:
    """A model that takes its guidance as an input answers each channel at that channel's scale:
    one call, the rows repeated once for each distinct scale; one scale for all is one plain pass."""
    calls = []

    def x0_fn(x: np.ndarray, t: np.ndarray, scale: np.ndarray) -> np.ndarray:
        calls.append(scale.copy())
        return x + scale[:, None, None]

    x = np.arange(12, dtype=np.float32).reshape(2, 2, 3)
    got = scaled_by_input(x0_fn, np.array([1.5, 2.5, 1.5], np.float32))(x, np.zeros(2, np.int64))
    np.testing.assert_array_equal(calls[0], [1.5, 1.5, 2.5, 2.5])
    np.testing.assert_array_equal(got, x + np.array([1.5, 2.5, 1.5], np.float32))
    calls.clear()
    np.testing.assert_array_equal(scaled_by_input(x0_fn, 2.0)(x, np.zeros(2, np.int64)), x + 2.0)
    np.testing.assert_array_equal(calls[0], [2.0, 2.0])


def test_known_frames_are_pinned() -> None:
    noise = np.random.default_rng(4).standard_normal((2, 10, 3)).astype(np.float32)
    known = np.full((2, 10, 3), 7.0, np.float32)
    mask = np.zeros((2, 10, 1), np.float32)
    mask[:, :4] = 1
    for out in (
        ddim_sample(lambda x, t: x * 0.1, noise, 5, ABAR, known, mask),
        dpm_solver_sample(lambda x, t: x * 0.1, noise, ddim_timesteps(5), ABAR, known, mask),
        consistency_sample(
            lambda x, t: x * 0.1, noise, 3, ABAR, 20, [np.random.default_rng(i) for i in range(2)], known, mask
        ),
    ):
        assert np.all(out[:, :4] == 7.0) and not np.any(out[:, 4:] == 7.0)


def test_a_take_is_the_same_alone_or_in_a_batch() -> None:
    def x0_fn(x: np.ndarray, t: np.ndarray) -> np.ndarray:
        return np.tanh(x) * (t[:, None, None] / 1000.0)

    noise = np.random.default_rng(5).standard_normal((3, 6, 2)).astype(np.float32)
    both = consistency_sample(x0_fn, noise, 4, ABAR, 20, [np.random.default_rng([7, i]) for i in range(3)])
    alone = consistency_sample(x0_fn, noise[1:2], 4, ABAR, 20, [np.random.default_rng([7, 1])])
    np.testing.assert_allclose(both[1:2], alone, rtol=1e-6)


def test_stochastic_ddim_keeps_the_forward_marginals_and_reaches_ddpm_at_eta_one() -> None:
    a, a_next = ABAR[700], ABAR[500]
    # eta 1: the DDPM posterior's variance, (1 - a_next) / (1 - a) * (1 - a / a_next)
    assert ddim_noise_scale(a, a_next, 1.0) ** 2 == pytest.approx((1 - a_next) / (1 - a) * (1 - a / a_next))
    assert ddim_noise_scale(a, a_next, 0.0) == 0.0
    rng = np.random.default_rng(0)
    eps, fresh = rng.standard_normal((2, 200_000))
    x0 = np.zeros_like(eps)
    x_t = noised(x0, eps, a)
    np.testing.assert_allclose(stochastic_ddim_step(x_t, x0, a, a_next, 0.0, fresh), ddim_step(x_t, x0, a, a_next))
    for eta in (0.5, 1.0):
        x_next = stochastic_ddim_step(x_t, x0, a, a_next, eta, fresh)
        assert x_next.var() == pytest.approx(1 - a_next, rel=0.02)  # still the marginal of step a_next
        kept = (1 - a_next - ddim_noise_scale(a, a_next, eta) ** 2) ** 0.5 / (1 - a_next) ** 0.5
        assert np.corrcoef(x_next, eps)[0, 1] == pytest.approx(kept, abs=0.01) and kept < 0.99


def test_stochastic_ddim_draws_from_each_take_s_generator() -> None:
    def x0_fn(x: np.ndarray, t: np.ndarray) -> np.ndarray:
        return 0.5 * np.tanh(x)

    noise = np.random.default_rng(6).standard_normal((3, 6, 2)).astype(np.float32)
    rngs = lambda seed: [np.random.default_rng([seed, i]) for i in range(3)]  # noqa: E731
    deterministic = ddim_sample(x0_fn, noise, 5, ABAR)
    stochastic = ddim_sample(x0_fn, noise, 5, ABAR, eta=1.0, rngs=rngs(7))
    assert not np.allclose(stochastic, deterministic)
    np.testing.assert_array_equal(stochastic, ddim_sample(x0_fn, noise, 5, ABAR, eta=1.0, rngs=rngs(7)))
    assert not np.allclose(stochastic, ddim_sample(x0_fn, noise, 5, ABAR, eta=1.0, rngs=rngs(8)))
    alone = ddim_sample(x0_fn, noise[1:2], 5, ABAR, eta=1.0, rngs=[np.random.default_rng([7, 1])])
    np.testing.assert_allclose(stochastic[1:2], alone, rtol=1e-6)
    with pytest.raises(ValueError, match="one generator a row"):
        ddim_sample(x0_fn, noise, 5, ABAR, eta=0.5)
