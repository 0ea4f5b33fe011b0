"""Augmentation for training: what real microphones, rooms and lines do to a dialogue, applied to
its log-mel features.

A model that learned from clean espeak-ng or studio speech must also meet other levels and voices,
telephone bands, rooms, noise and the other person's voice in its microphone (bleed). Each kind
works on a training window's (frames, 2, bands) log-mel as band energies, where these effects are
sums and products: voices and noise from one room add in energy (they are uncorrelated), a line
or a level multiplies each band, a room smears each band's energy forward in time, and a pitch or
speed change moves the energy along the frequency axis. That costs about a millisecond a
window, where changing the raw audio and computing its features again took about 0.1 s: sixteen
windows a step made each training step several times slower than the network's own work.
``tests/audio/test_augment.py`` checks each kind against the same change made to the audio.

Every kind is drawn from one generator seeded by ``(seed, step, example)``, so a run is the same
whatever the number of workers, and a resumed run continues exactly. The motion frames stay where
they are: ``speed`` is kept within ±3 % and anchored at the window's middle, so no frame moves by
more than 1.5 % of the window (a frame in 2 s).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.audio.logmel import DEFAULT_SPEC, MelSpec, band_average, band_centres, log_mel
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.plumbing.lazy_import import scipy_signal

KINDS = ("speed", "pitch", "reverb", "bleed", "level", "telephone", "noise")
"""In the order they apply: the voice, the room, the microphone, the line, the noise floor."""
BLEED_DB = (-20.0, -6.0)
TELEPHONE_HZ = (300.0, 3400.0)


def parse_kinds(text: str) -> tuple[str, ...]:
    """``"all"``, ``""`` (none) or a comma list of ``KINDS``; raises ValueError naming the unknown one."""
    names = [k.strip() for k in text.split(",") if k.strip()]
    if names == ["all"]:
        return KINDS
    unknown = [k for k in names if k not in KINDS]
    if unknown:
        raise ValueError(f"unknown augmentation {unknown[0]!r} (known: all, {', '.join(KINDS)})")
    return tuple(k for k in KINDS if k in names)


# ----------------------------------------------------------------- each kind, on band energies
# ``power``: (frames, bands) energies of one channel, or (frames, channels, bands).
def level(power: np.ndarray, db: float) -> np.ndarray:
    return power * 10 ** (db / 10)


def shift_frequency(power: np.ndarray, ratio: float, spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """Every band's energy moved up by ``ratio`` in frequency (harmonics and formants alike, as
    tape or a phase vocoder without formant correction do); interpolated in log energy."""
    centres = _centres(spec)
    source = np.interp(centres / ratio, centres, np.arange(len(centres)))
    return _read_between(power, source, axis=-1)


def warp_time(power: np.ndarray, factor: float) -> np.ndarray:
    """The frames played ``factor`` times faster, anchored at the middle frame (the edges repeat)."""
    frames = len(power)
    middle = (frames - 1) / 2
    source = np.clip(middle + (np.arange(frames) - middle) * factor, 0, frames - 1)
    return _read_between(power, source, axis=0)


def _read_between(power: np.ndarray, source: np.ndarray, axis: int) -> np.ndarray:
    """``power`` read along ``axis`` at fractional indices ``source`` (inside the axis), linearly
    between its neighbours in log energy."""
    lo = np.floor(source).astype(int)
    hi = np.minimum(lo + 1, power.shape[axis] - 1)
    shape = [1] * power.ndim
    shape[axis] = len(source)
    frac = (source - lo).reshape(shape)
    logs = np.log(power)
    return np.exp(np.take(logs, lo, axis=axis) * (1 - frac) + np.take(logs, hi, axis=axis) * frac)


def speed(power: np.ndarray, factor: float, spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """As tape played ``factor`` times faster: shorter in time and higher in pitch."""
    return shift_frequency(warp_time(power, factor), factor, spec)


def room_kernel(rt60: float, tail_db: float) -> np.ndarray:
    """Energy a frame leaves in the frames after it in a room: the direct sound, then a tail
    ``tail_db`` below it decaying by 60 dB in ``rt60`` seconds; unit sum (``synth.room_response``
    at the frame rate)."""
    frames = np.arange(int(np.ceil(rt60 * FPS)) + 1)
    tail = np.exp(-np.log(1e6) * frames / (rt60 * FPS))
    kernel = tail / tail.sum() * 10 ** (tail_db / 10)
    kernel[0] += 1.0
    return np.asarray(kernel / kernel.sum())


def reverb(power: np.ndarray, rt60: float, tail_db: float) -> np.ndarray:
    """Each frame plus the energy the frames before it left (the window's first frames get none)."""
    out = np.zeros_like(power)
    for lag, weight in enumerate(room_kernel(rt60, tail_db)[: len(power)]):
        out[lag:] += weight * power[: len(power) - lag]
    return out


def bleed(power: np.ndarray, db: float) -> np.ndarray:
    """(frames, 2, bands): each microphone also hears the other voice ``db`` below its own."""
    gain = 10 ** (db / 10)
    return power + gain * power[:, ::-1]


_centres = functools.cache(band_centres)


@functools.cache
def telephone_gains(spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """(bands,) a telephone line's energy gain per band (an 8th-order Butterworth band-pass)."""
    signal = scipy_signal()  # on first use: every training command imports this module
    sos = signal.butter(8, TELEPHONE_HZ, btype="bandpass", fs=ANALYSIS_RATE, output="sos")
    _, response = signal.sosfreqz(sos, worN=spec.n_fft // 2 + 1, fs=ANALYSIS_RATE)
    return band_average(spec, np.abs(response) ** 2)


@functools.cache
def white_noise_frames(spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """(frames, bands) band energies of unit-variance white noise, frame by frame (drawn from,
    so the added noise fluctuates as real noise does)."""
    noise = np.random.default_rng(0).standard_normal(4 * ANALYSIS_RATE)
    return np.exp(log_mel(noise, None, spec)[:, 0].astype(np.float64))


def noise(power: np.ndarray, snr_db: float, rng: np.random.Generator, spec: MelSpec = DEFAULT_SPEC) -> np.ndarray:
    """(frames, channels, bands) plus white noise ``snr_db`` below the louder channel's mean energy."""
    table = white_noise_frames(spec)
    loud = power.sum(axis=-1).mean(axis=0).max()
    variance = loud / table.mean(axis=0).sum() * 10 ** (-snr_db / 10)
    rows = rng.integers(len(table), size=power.shape[:-1])
    return power + variance * table[rows]


# ------------------------------------------------------------------------------ the augmentation
@dataclasses.dataclass(frozen=True)
class Augment:
    """Which kinds apply, each with chance ``probability`` per window."""

    kinds: tuple[str, ...]
    probability: float = 0.5

    def __call__(
        self, mel: np.ndarray, rng: np.random.Generator, spec: MelSpec = DEFAULT_SPEC
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """(frames, 2, bands) log-mel changed (float32), and what was done (kind: its parameters)."""
        power = np.exp(np.asarray(mel, np.float64))
        done: dict[str, Any] = {}
        for kind in KINDS:
            if kind in self.kinds and rng.random() < self.probability:
                power, done[kind] = _APPLY[kind](power, rng, spec)
        return np.log(np.maximum(power, spec.floor)).astype(np.float32), done


def _speed(power: np.ndarray, rng: np.random.Generator, spec: MelSpec) -> tuple[np.ndarray, Any]:
    factor = round(float(rng.uniform(0.97, 1.03)), 4)
    return speed(power, factor, spec), factor


def _per_channel(power: np.ndarray, rng: np.random.Generator, draw: Any, apply: Any) -> tuple[np.ndarray, Any]:
    params = [draw(rng) for _ in range(power.shape[1])]
    return np.stack([apply(power[:, c], p) for c, p in enumerate(params)], axis=1), params


def _pitch(power: np.ndarray, rng: np.random.Generator, spec: MelSpec) -> tuple[np.ndarray, Any]:
    def draw(r: np.random.Generator) -> float:
        return round(float(r.uniform(-3.0, 3.0)), 3)

    return _per_channel(power, rng, draw, lambda p, semitones: shift_frequency(p, 2 ** (semitones / 12), spec))


def _reverb(power: np.ndarray, rng: np.random.Generator, spec: MelSpec) -> tuple[np.ndarray, Any]:
    def draw(r: np.random.Generator) -> tuple[float, float]:
        return round(float(r.uniform(0.15, 0.7)), 3), round(float(r.uniform(-12.0, -2.0)), 2)

    return _per_channel(power, rng, draw, lambda p, room: reverb(p, *room))


def _bleed(power: np.ndarray, rng: np.random.Generator, spec: MelSpec) -> tuple[np.ndarray, Any]:
    db = round(float(rng.uniform(*BLEED_DB)), 2)
    return bleed(power, db), {"db": db}


def _level(power: np.ndarray, rng: np.random.Generator, spec: MelSpec) -> tuple[np.ndarray, Any]:
    return _per_channel(power, rng, lambda r: round(float(r.uniform(-12.0, 6.0)), 2), level)


def _telephone(power: np.ndarray, rng: np.random.Generator, spec: MelSpec) -> tuple[np.ndarray, Any]:
    return power * telephone_gains(spec), list(TELEPHONE_HZ)


def _noise(power: np.ndarray, rng: np.random.Generator, spec: MelSpec) -> tuple[np.ndarray, Any]:
    snr = round(float(rng.uniform(10.0, 35.0)), 2)
    return noise(power, snr, rng, spec), snr


_APPLY = {
    "speed": _speed,
    "pitch": _pitch,
    "reverb": _reverb,
    "bleed": _bleed,
    "level": _level,
    "telephone": _telephone,
    "noise": _noise,
}
