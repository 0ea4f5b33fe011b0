"""Streaming resampling equals resampling at once, whatever the block sizes."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from scipy.signal import resample_poly

from convodrive.audio.resample import StreamResampler


@pytest.mark.parametrize("rate_in, rate_out", [(44100, 16000), (48000, 16000), (16000, 22050), (16000, 16000)])
def test_blocks_of_any_size_join_seamlessly(rate_in: int, rate_out: int) -> None:
    rng = np.random.default_rng(rate_in + rate_out)
    signal = rng.standard_normal(int(1.7 * rate_in)).astype(np.float32)
    resampler = StreamResampler(rate_in, rate_out)
    pieces, pos = [], 0
    while pos < len(signal):
        n = int(rng.integers(1, 3000))
        pieces.append(resampler.push(signal[pos : pos + n]))
        pos += n
    pieces.append(resampler.finish())
    got = np.concatenate(pieces)
    ratio = Fraction(rate_out, rate_in)
    want = resample_poly(signal.astype(np.float64), ratio.numerator, ratio.denominator)
    assert len(got) == len(want)
    np.testing.assert_allclose(got, want, atol=2e-5)


def test_holds_back_only_its_context() -> None:
    resampler = StreamResampler(48000, 16000)
    out = resampler.push(np.ones(48000, np.float32))
    assert len(out) == (48000 - resampler.latency_samples) // 3
    assert resampler.latency_samples / 48000 < 0.002
