"""Diffusion sampling in NumPy around a graph that predicts clean motion (x0) from noisy motion.

One definition of the noise schedule serves training (torch reads these arrays) and the runtime,
so a model is sampled on the schedule it learned. The loops:

- ``ddim_sample``: DDIM with any number of steps, spaced "trailing" (the first step starts at the
  last diffusion step, so even one step starts from pure noise); deterministic at ``eta`` 0,
  adding fresh noise at each step as DDPM does at ``eta`` 1.
- ``dpm_solver_sample``: DPM-Solver++(2M) (Lu et al. 2022) on given steps (DDIM's trailing ones,
  or ``log_snr_timesteps``): its first step is DDIM's, each later one extrapolates from the last
  two x0 in log-SNR, a second-order solver of the same ODE for one call a step.
- ``consistency_sample``: a distilled consistency model, which maps any noisy point straight to
  x0; with more than one step, x0 is noised again to the next (lower) step with fresh noise.
- ``guided``: classifier-free guidance with the conditional and unconditional passes as one
  batch (the first half conditional), combined as ``uncond + scale * (cond - uncond)`` on x0.
- ``scaled_by_input``: a guidance-distilled model, whose scale is an input, at one scale a
  channel: one pass a distinct scale, as one batch.

All loops pin known frames (the previous window's last frames): every x0 gets them copied in, so
a window continues its predecessor exactly (continuation by inpainting; the networks also see
them as an input). Random numbers come from one generator per take (row), drawn in a fixed
order, so a take is the same whether it runs alone or beside others.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

X0Fn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(x_t (B, T, D), steps (B,) int64) -> x0 (B, T, D)."""
T = TypeVar("T")


def noised(x0: T, noise: T, alpha_bar: Any) -> T:
    """The forward process at a step whose signal fraction is ``alpha_bar``: sqrt(a) x0 +
    sqrt(1 - a) noise. Plain arithmetic, so NumPy arrays and torch tensors (training) both work."""
    return alpha_bar**0.5 * x0 + (1 - alpha_bar) ** 0.5 * noise  # type: ignore[operator]


def predicted_noise(x: T, x0: T, alpha_bar: Any) -> T:
    """The noise that takes ``x0`` to ``x`` at a step with signal fraction ``alpha_bar`` (the
    forward process solved for it; NumPy or torch)."""
    return (x - alpha_bar**0.5 * x0) / (1 - alpha_bar) ** 0.5  # type: ignore[operator, no-any-return]


def ddim_step(x: T, x0: T, alpha_bar: Any, alpha_bar_next: Any) -> T:
    """Deterministic DDIM (eta 0) from ``x`` at a step with signal fraction ``alpha_bar`` to the
    step with ``alpha_bar_next``, given the predicted clean ``x0`` (NumPy or torch)."""
    return noised(x0, predicted_noise(x, x0, alpha_bar), alpha_bar_next)


def ddim_noise_scale(alpha_bar: float, alpha_bar_next: float, eta: float) -> float:
    """The standard deviation of the fresh noise a DDIM step with ``eta`` adds (Song et al. 2021,
    eq. 16): 0 at eta 0, the DDPM posterior's at eta 1."""
    return float(eta * ((1 - alpha_bar_next) / (1 - alpha_bar) * (1 - alpha_bar / alpha_bar_next)) ** 0.5)


def stochastic_ddim_step(
    x: np.ndarray, x0: np.ndarray, alpha_bar: float, alpha_bar_next: float, eta: float, fresh: np.ndarray
) -> np.ndarray:
    """A DDIM step that keeps part of the predicted noise and draws the rest afresh (``fresh``,
    standard normal, the shape of ``x``): the variance stays that of the forward process."""
    sigma = ddim_noise_scale(alpha_bar, alpha_bar_next, eta)
    eps = predicted_noise(x, x0, alpha_bar)
    return alpha_bar_next**0.5 * x0 + (1 - alpha_bar_next - sigma**2) ** 0.5 * eps + sigma * fresh


def cosine_schedule(steps: int = 1000, offset: float = 0.008, max_beta: float = 0.999) -> np.ndarray:
    """Cumulative signal fractions alpha_bar (steps,) float64 of the cosine schedule (Nichol and
    Dhariwal, improved DDPM; the reference's default): step t keeps sqrt(alpha_bar[t]) of x0."""
    t = np.arange(steps + 1, dtype=np.float64) / steps
    f = np.cos((t + offset) / (1 + offset) * np.pi / 2) ** 2
    betas = np.minimum(1 - f[1:] / f[:-1], max_beta)
    return np.cumprod(1 - betas)


def ddim_timesteps(count: int, total: int = 1000) -> np.ndarray:
    """``count`` diffusion steps out of ``total``, descending and evenly spaced, the first the
    last step (``total - 1``): "trailing" spacing (Lin et al. 2024)."""
    if not 1 <= count <= total:
        raise ValueError(f"steps must be between 1 and {total}, got {count}")
    return (np.round(np.arange(total, 0, -total / count)).astype(np.int64) - 1)[:count]


def grid_timesteps(count: int, total: int, skip: int) -> np.ndarray:
    """``count`` steps of the consistency-distillation grid (every ``skip``-th step, ending at
    ``skip - 1``), descending from the last step, evenly spaced on the grid."""
    points = total // skip
    if not 1 <= count <= points:
        raise ValueError(f"a distilled sampler takes 1 to {points} steps, got {count}")
    return (np.round(np.arange(points, 0, -points / count)).astype(np.int64) * skip - 1)[:count]


def noise_like(rngs: Sequence[np.random.Generator], shape: tuple[int, ...]) -> np.ndarray:
    """(len(rngs), *shape) float32 standard normal noise, row b from ``rngs[b]``."""
    return np.stack([rng.standard_normal(shape, dtype=np.float32) for rng in rngs])


def pin(x0: np.ndarray, known: np.ndarray | None, known_mask: np.ndarray | None) -> np.ndarray:
    if known is None or known_mask is None:
        return x0
    return known_mask * known + (1 - known_mask) * x0


def guided(x0_fn: X0Fn, scale: float | np.ndarray) -> X0Fn:
    """x0 with classifier-free guidance. ``x0_fn`` gets the batch twice (conditional rows first,
    then the same rows unconditional) in one call; scale 1 is the conditional model alone. An
    array of scales, one a channel, guides each channel by its own (it broadcasts over the last axis)."""

    def fn(x: np.ndarray, steps: np.ndarray) -> np.ndarray:
        both = x0_fn(np.concatenate([x, x]), np.concatenate([steps, steps]))
        cond, uncond = both[: len(x)], both[len(x) :]
        return uncond + scale * (cond - uncond)

    return fn


ScaledX0Fn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""x0 of a model that takes its guidance scale as an input: (x, steps, scale a row)."""


def distinct_scales(scale: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct values of one scale or one a channel, smallest first, and each channel's index among them."""
    levels, level_of_channel = np.unique(np.atleast_1d(np.asarray(scale, np.float32)), return_inverse=True)
    return levels, level_of_channel


def scaled_by_input(x0_fn: ScaledX0Fn, scale: float | np.ndarray) -> X0Fn:
    """x0 at one guidance scale a channel (or one for all) from a model that learned the scale as an
    input: the rows go once for each of ``distinct_scales`` in one call (copy k at the k-th
    smallest), and each channel is read from its own scale's copy."""
    levels, level_of_channel = distinct_scales(scale)

    def fn(x: np.ndarray, steps: np.ndarray) -> np.ndarray:
        rows = len(x)
        out = x0_fn(np.concatenate([x] * len(levels)), np.concatenate([steps] * len(levels)), np.repeat(levels, rows))
        if len(levels) == 1:
            return out
        copies = out.reshape(len(levels), rows, *out.shape[1:])
        channels = np.arange(out.shape[-1])
        return np.moveaxis(copies[level_of_channel, ..., channels], 0, -1)

    return fn


def ddim_sample(
    x0_fn: X0Fn,
    noise: np.ndarray,
    steps: int,
    alpha_bar: np.ndarray,
    known: np.ndarray | None = None,
    known_mask: np.ndarray | None = None,
    eta: float = 0.0,
    rngs: Sequence[np.random.Generator] = (),
) -> np.ndarray:
    """x0 (B, T, D) by DDIM from ``noise`` (B, T, D) in ``steps`` steps; with ``eta`` above 0,
    each step draws fresh noise from ``rngs`` (one a row)."""
    if eta > 0 and len(rngs) != len(noise):
        raise ValueError(f"stochastic DDIM needs one generator a row, got {len(rngs)} for {len(noise)}")
    x = noise.astype(np.float32)
    times = ddim_timesteps(steps, len(alpha_bar))
    x0 = x
    for i, t in enumerate(times):
        x0 = pin(x0_fn(x, np.full(len(x), t, np.int64)).astype(np.float32), known, known_mask)
        if i + 1 == len(times):
            break
        a, a_next = alpha_bar[t], alpha_bar[times[i + 1]]
        if eta > 0:
            x = stochastic_ddim_step(x, x0, a, a_next, eta, noise_like(rngs, x.shape[1:])).astype(np.float32)
        else:
            x = ddim_step(x, x0, a, a_next).astype(np.float32)
    return x0


def log_snr(alpha_bar: np.ndarray) -> np.ndarray:
    """lambda = log(alpha / sigma) (half the log signal-to-noise ratio), DPM-Solver's time variable."""
    return np.asarray(0.5 * np.log(alpha_bar / (1 - alpha_bar)))


def log_snr_timesteps(count: int, alpha_bar: np.ndarray, floor: float = 1e-4) -> np.ndarray:
    """``count`` diffusion steps evenly spaced in log-SNR, descending, the last step 0. They start at
    the last step whose signal fraction reaches ``floor``: the cosine schedule's clipped tail sends
    log-SNR from -4.6 to -9.9 in its last 7 steps, where x is noise all the same, and spacing over
    it would spend calls there. Raises ValueError where steps would repeat (above 40 on the 1000-step
    cosine schedule: log-SNR moves fast between its first and last few steps)."""
    if count < 1:
        raise ValueError(f"steps must be at least 1, got {count}")
    lam = log_snr(alpha_bar)
    top = int(np.nonzero(alpha_bar >= floor)[0][-1])
    if count == 1:
        return np.array([top], np.int64)
    # lambda falls with the step; searchsorted wants it rising
    rising = lam[: top + 1][::-1]
    targets = np.linspace(lam[top], lam[0], count)
    index = np.clip(np.searchsorted(rising, targets), 1, top)
    nearer = np.where(targets - rising[index - 1] < rising[index] - targets, index - 1, index)
    times = (top - nearer).astype(np.int64)
    times[0], times[-1] = top, 0
    if np.any(np.diff(times) >= 0):
        raise ValueError(f"{count} steps evenly spaced in log-SNR would repeat steps of this schedule")
    return times


def dpm_solver_sample(
    x0_fn: X0Fn,
    noise: np.ndarray,
    times: np.ndarray,
    alpha_bar: np.ndarray,
    known: np.ndarray | None = None,
    known_mask: np.ndarray | None = None,
) -> np.ndarray:
    """x0 (B, T, D) by DPM-Solver++(2M) from ``noise``, one call at each of ``times`` (descending,
    e.g. ``ddim_timesteps`` or ``log_snr_timesteps``); deterministic. The last x0 is the answer, as
    with ``ddim_sample``, whose first step is also this one's."""
    x = noise.astype(np.float32)
    lam = log_snr(alpha_bar)
    x0 = x
    earlier: tuple[np.ndarray, float] | None = None
    for i, t in enumerate(times):
        x0 = pin(x0_fn(x, np.full(len(x), t, np.int64)).astype(np.float32), known, known_mask)
        if i + 1 == len(times):
            break
        a, a_next = float(alpha_bar[t]), float(alpha_bar[times[i + 1]])
        h = float(lam[times[i + 1]] - lam[t])
        slope = x0
        if earlier is not None:  # second order: extrapolate x0 along log-SNR from the last two
            x0_before, h_before = earlier
            half_ratio = h / (2 * h_before)
            slope = (1 + half_ratio) * x0 - half_ratio * x0_before
        x = (((1 - a_next) / (1 - a)) ** 0.5 * x - a_next**0.5 * np.expm1(-h) * slope).astype(np.float32)
        earlier = (x0, h)
    return x0


def consistency_sample(
    x0_fn: X0Fn,
    noise: np.ndarray,
    steps: int,
    alpha_bar: np.ndarray,
    skip: int,
    rngs: Sequence[np.random.Generator],
    known: np.ndarray | None = None,
    known_mask: np.ndarray | None = None,
) -> np.ndarray:
    """x0 (B, T, D) from a consistency model in ``steps`` evaluations (multistep consistency
    sampling: x0, then noised to the next grid step with fresh noise from ``rngs``)."""
    x = noise.astype(np.float32)
    times = grid_timesteps(steps, len(alpha_bar), skip)
    x0 = x
    for i, t in enumerate(times):
        x0 = pin(x0_fn(x, np.full(len(x), t, np.int64)).astype(np.float32), known, known_mask)
        if i + 1 == len(times):
            break
        x = noised(x0, noise_like(rngs, x.shape[1:]), alpha_bar[times[i + 1]]).astype(np.float32)
    return x0
