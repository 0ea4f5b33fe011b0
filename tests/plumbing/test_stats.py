"""Latency histograms: percentiles in bounded memory."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.plumbing.stats import Histogram, percentiles


def test_percentiles_match_numpy_to_one_bin() -> None:
    values = np.random.default_rng(0).gamma(4.0, 10.0, 20000)
    hist = Histogram()
    for v in values:
        hist.add(float(v))
    summary = hist.summary()
    assert summary is not None and summary["count"] == len(values)
    assert summary["p50"] == pytest.approx(np.percentile(values, 50), abs=0.1)
    assert summary["p99"] == pytest.approx(np.percentile(values, 99), abs=0.1)
    assert summary["max"] == pytest.approx(values.max(), abs=0.05)
    assert Histogram().summary() is None


def test_exact_percentiles_are_numpys_and_scaled() -> None:
    values = np.random.default_rng(3).exponential(0.004, 500)
    got = percentiles(values.tolist(), scale=1000.0)
    assert got is not None and set(got) == {"p50", "p99", "max"}
    assert abs(got["p50"] - np.percentile(values, 50) * 1000) < 1e-3
    assert abs(got["p99"] - np.percentile(values, 99) * 1000) < 1e-3
    assert abs(got["max"] - values.max() * 1000) < 1e-3
    assert percentiles([]) is None
