"""Training augmentation (audio.augment): seeded, and each kind, made on log-mel band energies,
does what the same change made to the audio does to its features."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, sosfilt

from convodrive.audio import augment as aug
from convodrive.audio.logmel import band_centres, log_mel
from convodrive.audio.synth import add_bleed

RATE = 16000


def _voice(seed: int, seconds: float = 2.0, f0: float = 140.0) -> np.ndarray:
    """A buzzy voice-like signal: harmonics of ``f0`` up to 7 kHz under a syllable envelope."""
    t = np.arange(int(seconds * RATE)) / RATE
    rng = np.random.default_rng(seed)
    x = sum(np.sin(2 * np.pi * f0 * k * t + rng.uniform(0, 6.28)) / k for k in range(1, int(7000 / f0)))
    return (0.2 * x * (0.6 + 0.4 * np.sin(2 * np.pi * 4 * t)) / np.abs(x).max()).astype(np.float32)


def _stereo() -> np.ndarray:
    return np.stack([_voice(1), _voice(2, f0=210.0)], axis=1)


def _power(samples: np.ndarray) -> np.ndarray:
    """Band energies: (frames, bands) of one channel, (frames, 2, bands) of two."""
    power = np.exp(log_mel(samples).astype(np.float64))
    return power[:, 0] if np.ndim(samples) == 1 else power


def _band_db(power: np.ndarray) -> np.ndarray:
    """Each band's mean energy over the frames, in dB."""
    return 10 * np.log10(power.mean(axis=0))


def test_the_same_seed_gives_the_same_features_and_another_seed_others() -> None:
    every = aug.Augment(aug.KINDS, probability=1.0)
    mel = log_mel(_stereo())
    a, done_a = every(mel, np.random.default_rng([3, 7, 11]))
    b, done_b = every(mel, np.random.default_rng([3, 7, 11]))
    c, _ = every(mel, np.random.default_rng([3, 8, 11]))
    assert np.array_equal(a, b) and done_a == done_b
    assert set(done_a) == set(aug.KINDS)
    assert np.abs(a - c).mean() > 0.1
    assert a.shape == mel.shape and a.dtype == np.float32
    unchanged, done = aug.Augment(aug.KINDS, probability=0.0)(mel, np.random.default_rng(0))
    assert done == {} and np.array_equal(unchanged, mel)


@pytest.mark.parametrize("db", [-20.0, -12.0, -6.0])
def test_bleed_matches_the_voices_mixed_in_the_audio(db: float) -> None:
    x = _stereo()
    mixed = np.stack(add_bleed(x[:, 0], x[:, 1], db, 3.0, seed=5), axis=1)
    made = aug.bleed(_power(x), db)
    # Per band, over the window: within 1.5 dB on average of the audio mixed through a room (whose
    # response, not flat, colours the bleed by a dB or two band to band).
    assert np.abs(_band_db(made[:, 0]) - _band_db(_power(mixed)[:, 0])).mean() < 1.5
    assert np.abs(_band_db(made[:, 1]) - _band_db(_power(mixed)[:, 1])).mean() < 1.5


def test_telephone_matches_the_band_pass_filter_on_the_audio() -> None:
    x = _voice(4)
    sos = butter(8, aug.TELEPHONE_HZ, btype="bandpass", fs=RATE, output="sos")
    filtered = _band_db(_power(sosfilt(sos, x)))
    made = _band_db(_power(x) * aug.telephone_gains())
    centres = band_centres()
    inside, above = (centres > 500) & (centres < 3000), (centres > 4500) & (centres < 6800)
    assert np.abs(made[inside] - filtered[inside]).max() < 1.5
    assert (_band_db(_power(x))[above] - made[above]).min() > 25.0
    assert (_band_db(_power(x))[above] - filtered[above]).min() > 25.0


def test_noise_fills_the_silence_as_white_noise_in_the_audio_does() -> None:
    x = _voice(6)
    x[RATE:] = 0
    power = _power(np.stack([x, x], axis=1))
    made = aug.noise(power, 20.0, np.random.default_rng(0))
    # The same noise made in the audio: its variance 20 dB below the voice's in-band energy.
    sigma = np.sqrt(np.mean(x[:RATE].astype(np.float64) ** 2) / 2 * 10 ** (-20 / 10))
    heard = _power(x + np.random.default_rng(1).normal(0, sigma, len(x)))
    silent = slice(32, 58)
    assert abs(10 * np.log10(made[silent, 0].sum(-1).mean() / heard[silent].sum(-1).mean())) < 1.5


def test_pitch_moves_a_tone_to_the_band_of_the_higher_tone() -> None:
    t = np.arange(2 * RATE) / RATE
    tone = lambda hz: (0.3 * np.sin(2 * np.pi * hz * t)).astype(np.float32)  # noqa: E731
    moved = aug.shift_frequency(_power(tone(300.0)), 2 ** (5 / 12))
    target = _power(tone(300.0 * 2 ** (5 / 12)))
    assert abs(int(np.argmax(moved.mean(0))) - int(np.argmax(target.mean(0)))) <= 1
    assert abs(_band_db(moved).max() - _band_db(target).max()) < 3.0


def test_speed_keeps_the_middle_and_moves_the_rest_towards_it() -> None:
    frames = 181
    power = np.full((frames, 2, 80), 1e-6)
    power[150:] = 1.0  # the voice starts 60 frames after the middle frame (90)
    fast = aug.warp_time(power, 1.03)
    onset = int(np.argmax(fast[:, 0, 0] > 0.5))
    assert onset == 90 + int(np.ceil(60 / 1.03))
    assert np.allclose(fast[90], power[90])
    assert np.allclose(aug.speed(np.ones((frames, 2, 80)), 1.03), 1.0)


def test_reverb_keeps_the_energy_and_leaves_a_tail_after_the_voice() -> None:
    power = np.full((120, 80), 1e-8)
    power[20:40] = 1.0
    wet = aug.reverb(power, 0.5, -3.0)
    assert abs(wet.sum() / power.sum() - 1) < 1e-6
    tail = wet[40:55, 0]  # 60 dB down in 0.5 s (15 frames)
    assert (tail[:6] > 1e-3).all() and (np.diff(tail) < 0).all() and np.isclose(wet[56, 0], power[56, 0])
    assert np.allclose(aug.room_kernel(0.3, -6.0).sum(), 1.0)


def test_level_scales_the_energy() -> None:
    power = _power(_stereo())
    assert np.allclose(aug.level(power, -6.0), power * 10 ** (-0.6))


def test_unknown_kinds_are_refused_by_name() -> None:
    assert aug.parse_kinds("all") == aug.KINDS and aug.parse_kinds("") == ()
    assert aug.parse_kinds("noise, bleed") == ("bleed", "noise")
    with pytest.raises(ValueError, match="'echo'"):
        aug.parse_kinds("noise,echo")
