"""The papers' distribution and diversity metrics, on arrays of per-frame feature vectors.

Definitions (shared/reference LEARNED.md §1):
- FD_g (audio2photoreal): Fréchet distance between the per-frame vectors of generated and real
  motion (static poses / expressions); FD_k the same on frame-to-frame velocities.
- Div_g: mean L2 distance between 30 random pairs of frames of one sequence.
- Div_k: temporal variance of a sequence (mean over dimensions of the variance over time).
- Div_sample (audio2photoreal) and Var (ProbTalk): variance across the samples generated for one
  audio (mean over frames and dimensions of the variance over samples). One function serves both;
  the paper names differ in the slice they are reported on.
- FGD (ProbTalk): the Fréchet distance between autoencoder features of real and generated
  windows (``convodrive.eval.fgd``); the formula is ``frechet_distance`` below.

Inputs are the normalised learning representation (``convodrive.motion.representation``), so a
metric weighs every dimension alike and the figures compare across corpora with the same stats.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg

DIV_G_PAIRS = 30


def frechet_distance(a: np.ndarray, b: np.ndarray, eps: float = 1e-6) -> float:
    """Fréchet distance between Gaussians fitted to the rows of ``a`` (N, D) and ``b`` (M, D).

    The pytorch-fid formula: |mu_a - mu_b|^2 + tr(Sa + Sb - 2 sqrt(Sa Sb)), with ``eps`` added to
    the diagonals when the product is singular.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"frechet_distance needs (N, D) and (M, D) arrays, got {a.shape} and {b.shape}")
    if len(a) < 2 or len(b) < 2:
        raise ValueError("frechet_distance needs at least two rows on each side")
    mu_a, mu_b = a.mean(0), b.mean(0)
    cov_a, cov_b = np.atleast_2d(np.cov(a, rowvar=False)), np.atleast_2d(np.cov(b, rowvar=False))
    with warnings.catch_warnings():  # a singular product is expected with few frames; handled below
        warnings.simplefilter("ignore", linalg.LinAlgWarning)
        covmean = linalg.sqrtm(cov_a @ cov_b)
        if not np.isfinite(covmean).all():
            offset = np.eye(len(cov_a)) * eps
            covmean = linalg.sqrtm((cov_a + offset) @ (cov_b + offset))
    covmean = np.real(covmean)
    diff = mu_a - mu_b
    return float(max(0.0, diff @ diff + np.trace(cov_a) + np.trace(cov_b) - 2.0 * np.trace(covmean)))


def velocities(sequences: list[np.ndarray]) -> np.ndarray:
    """Frame-to-frame differences of every sequence, stacked: (sum(T_i - 1), D)."""
    return np.concatenate([np.diff(np.asarray(s, np.float64), axis=0) for s in sequences if len(s) > 1])


def fd_g(generated: list[np.ndarray], real: list[np.ndarray]) -> float:
    return frechet_distance(np.concatenate(generated), np.concatenate(real))


def fd_k(generated: list[np.ndarray], real: list[np.ndarray]) -> float:
    return frechet_distance(velocities(generated), velocities(real))


def div_g(sequence: np.ndarray, rng: np.random.Generator, pairs: int = DIV_G_PAIRS) -> float:
    """Mean L2 distance between ``pairs`` random pairs of distinct frames of one (T, D) sequence."""
    seq = np.asarray(sequence, np.float64)
    if len(seq) < 2:
        return 0.0
    i = rng.integers(0, len(seq), pairs)
    j = (i + rng.integers(1, len(seq), pairs)) % len(seq)
    return float(np.linalg.norm(seq[i] - seq[j], axis=1).mean())


def div_k(sequence: np.ndarray) -> float:
    """Temporal variance: mean over dimensions of the variance over time of one (T, D) sequence."""
    seq = np.asarray(sequence, np.float64)
    return float(seq.var(axis=0).mean()) if len(seq) > 1 else 0.0


def sample_variance(samples: np.ndarray) -> float:
    """Variance across K samples (K, T, D) for one audio: mean over frames and dimensions."""
    samples = np.asarray(samples, np.float64)
    if samples.ndim != 3:
        raise ValueError(f"sample_variance needs (K, T, D), got {samples.shape}")
    return float(samples.var(axis=0).mean()) if len(samples) > 1 else 0.0
