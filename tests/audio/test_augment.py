"""Training augmentation (audio.augment): seeded, and each kind changes what it should."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import welch

from convodrive.audio import augment as aug

RATE = 16000


def _voice(seed: int, seconds: float = 2.0, f0: float = 140.0) -> np.ndarray:
    """A buzzy voice-like signal: harmonics of ``f0`` up to 7 kHz under a syllable envelope."""
    t = np.arange(int(seconds * RATE)) / RATE
    rng = np.random.default_rng(seed)
    x = sum(np.sin(2 * np.pi * f0 * k * t + rng.uniform(0, 6.28)) / k for k in range(1, int(7000 / f0)))
    return (0.2 * x * (0.6 + 0.4 * np.sin(2 * np.pi * 4 * t)) / np.abs(x).max()).astype(np.float32)


def _stereo() -> np.ndarray:
    return np.stack([_voice(1), _voice(2, f0=210.0)], axis=1)


def _band_db(x: np.ndarray, lo: float, hi: float) -> float:
    f, p = welch(x, RATE, nperseg=1024)
    return 10 * np.log10(p[(f >= lo) & (f < hi)].sum() + 1e-20)


def test_the_same_seed_gives_the_same_audio_and_another_seed_other_audio() -> None:
    every = aug.Augment(aug.KINDS, probability=1.0)
    a, done_a = every(_stereo(), np.random.default_rng([3, 7, 11]))
    b, done_b = every(_stereo(), np.random.default_rng([3, 7, 11]))
    c, _ = every(_stereo(), np.random.default_rng([3, 8, 11]))
    assert np.array_equal(a, b) and done_a == done_b
    assert set(done_a) == set(aug.KINDS)
    assert np.abs(a - c).max() > 0.01
    assert a.shape == _stereo().shape and np.abs(a).max() <= 1.0


def test_telephone_band_removes_the_energy_above_3_4_khz_and_keeps_the_voice() -> None:
    x = _voice(4)
    y = aug.telephone(x)
    assert _band_db(x, 4000, 8000) - _band_db(y, 4000, 8000) > 25.0
    assert abs(_band_db(x, 500, 3000) - _band_db(y, 500, 3000)) < 1.5


@pytest.mark.parametrize("db", [-20.0, -12.0, -6.0])
def test_bleed_adds_the_other_channel_at_the_requested_level(db: float) -> None:
    x = _stereo()
    a, b = aug.add_bleed(x[:, 0], x[:, 1], db, 3.0, seed=5)
    for added, source in ((a - x[:, 0], x[:, 1]), (b - x[:, 1], x[:, 0])):
        measured = 10 * np.log10(np.sum(added.astype(np.float64) ** 2) / np.sum(source.astype(np.float64) ** 2))
        assert abs(measured - db) < 1.0


def test_level_speed_pitch_reverb_and_noise_each_change_what_they_should() -> None:
    x = _voice(6)
    assert np.allclose(aug.level(x, -6.0), x * 10 ** (-6 / 20))
    # Pitch: a tone moves by the ratio, its length and level stay.
    tone = (0.3 * np.sin(2 * np.pi * 200.0 * np.arange(2 * RATE) / RATE)).astype(np.float32)
    shifted = aug.pitch(tone, 3.0)
    f, p1 = welch(shifted[2000:-2000], RATE, nperseg=4096)
    assert abs(f[np.argmax(p1)] - 200.0 * 2 ** (3 / 12)) < 6.0
    assert len(shifted) == len(tone) and abs(np.std(shifted[2000:-2000]) / np.std(tone) - 1) < 0.2
    f, p0 = welch(x, RATE, nperseg=4096)
    low = f < 400
    # Speed: the same length, the pitch up with it, the middle sample where it was.
    stereo = np.stack([x, x], axis=1)
    fast = aug.speed(stereo, 1.03)
    assert fast.shape == stereo.shape
    _, p2 = welch(fast[:, 0], RATE, nperseg=4096)
    assert abs(f[low][np.argmax(p2[low])] / f[low][np.argmax(p0[low])] - 1.03) < 0.02
    # Reverb: a tail after the voice stops; noise: the silence is no longer silent.
    gated = x.copy()
    gated[RATE:] = 0
    wet = aug.reverb(gated, 0.5, -3.0, seed=1)
    assert np.sqrt(np.mean(wet[RATE + 800 : RATE + 3200] ** 2)) > 1e-3
    noisy = aug.noise(gated, 0.01, np.random.default_rng(0))
    assert abs(np.std(noisy[RATE:]) - 0.01) < 1e-3


def test_unknown_kinds_are_refused_by_name() -> None:
    assert aug.parse_kinds("all") == aug.KINDS and aug.parse_kinds("") == ()
    assert aug.parse_kinds("noise, bleed") == ("bleed", "noise")
    with pytest.raises(ValueError, match="'echo'"):
        aug.parse_kinds("noise,echo")
