"""Latency histograms: percentiles in bounded memory."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.plumbing.stats import Histogram


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
