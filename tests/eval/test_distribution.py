"""The distribution, diversity and beat metrics on arrays whose answers are known."""

from __future__ import annotations

import numpy as np

from convodrive.eval.beats import beat_consistency
from convodrive.eval.distribution import div_g, div_k, fd_k, frechet_distance, sample_variance


def test_frechet_distance_of_gaussians_matches_the_closed_form() -> None:
    rng = np.random.default_rng(0)
    a = rng.standard_normal((20000, 3))
    assert frechet_distance(a, a) < 1e-9
    shifted = a + np.array([2.0, 0.0, 0.0])
    assert abs(frechet_distance(a, shifted) - 4.0) < 1e-6  # |mu difference|^2, same covariance
    scaled = rng.standard_normal((20000, 3)) * 2.0  # tr(S1 + S2 - 2 sqrt(S1 S2)) = 3 * (1 + 4 - 4)
    assert abs(frechet_distance(a, scaled) - 3.0) < 0.1


def test_velocity_distance_sees_jitter_that_static_distance_misses() -> None:
    rng = np.random.default_rng(1)
    smooth = [np.cumsum(rng.standard_normal((500, 2)) * 0.01, axis=0) for _ in range(4)]
    jittery = [s + rng.standard_normal(s.shape) * 0.05 for s in smooth]
    assert fd_k(jittery, smooth) > 10 * fd_k(smooth[:2], smooth[2:])


def test_diversity_figures() -> None:
    rng = np.random.default_rng(2)
    still = np.zeros((100, 4))
    moving = rng.standard_normal((100, 4))
    assert div_g(still, rng) == 0.0 and div_g(moving, rng) > 1.0
    assert div_k(still) == 0.0 and abs(div_k(moving) - 1.0) < 0.3
    same = np.stack([moving, moving, moving])
    assert sample_variance(same) < 1e-20 and sample_variance(rng.standard_normal((4, 50, 3))) > 0.5


def test_beat_consistency() -> None:
    onsets = np.array([1.0, 2.0, 3.0])
    assert beat_consistency(onsets, onsets) == 1.0
    assert beat_consistency(onsets, onsets + 0.1) < 0.7
    assert beat_consistency(onsets, np.zeros(0)) == 0.0 and beat_consistency(np.zeros(0), onsets) is None
