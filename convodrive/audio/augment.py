"""Audio augmentation for training: what real microphones, rooms and lines do to a dialogue.

A training window's raw two-channel audio (self, partner) is changed before its features are
computed, so a model that learned from clean espeak-ng or studio speech also meets levels,
voices, telephone bands, rooms, noise and the other person's voice in its microphone (bleed).
Every kind is drawn from one generator seeded by ``(seed, step, example)``, so a run is the same
whatever the number of workers, and a resumed run continues exactly.

The motion frames stay where they are: ``speed`` is kept within ±3 % and anchored at the
window's middle, so no sample moves by more than 1.5 % of the window (30 ms in 2 s, a frame).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy.signal import butter, fftconvolve, istft, resample_poly, sosfilt, stft

from convodrive.audio.source import ANALYSIS_RATE
from convodrive.audio.synth import add_bleed, room_response

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


def level(x: np.ndarray, db: float) -> np.ndarray:
    return x * np.float32(10 ** (db / 20))


def speed(stereo: np.ndarray, factor: float) -> np.ndarray:
    """Both channels played ``factor`` times faster (pitch with it, as tape), the same length,
    anchored at the middle."""
    n = len(stereo)
    up = 200
    down = int(round(up * factor))
    fast = resample_poly(stereo, up, down, axis=0).astype(np.float32)
    middle, half = len(fast) // 2, n // 2
    out = np.zeros_like(stereo)
    lo = middle - half
    take = fast[max(lo, 0) : max(lo, 0) + n - max(-lo, 0)]
    out[max(-lo, 0) : max(-lo, 0) + len(take)] = take
    return out


def pitch(x: np.ndarray, semitones: float) -> np.ndarray:
    """One channel's voice ``semitones`` higher at the same timing: each short-time spectrum's bins
    move up by the ratio, and each bin's phase advances at its new frequency (a phase vocoder)."""
    ratio = 2 ** (semitones / 12)
    size, hop = 512, 128
    _, _, spec = stft(x, nperseg=size, noverlap=size - hop)
    bins = np.arange(spec.shape[0])
    omega = (2 * np.pi * hop / size) * bins[:, None]
    angle = np.angle(spec)
    step = np.diff(angle, axis=1, prepend=angle[:, :1]) - omega
    freq = omega + (step + np.pi) % (2 * np.pi) - np.pi  # each bin's true phase advance per hop
    src = bins / ratio
    inside = (src <= bins[-1])[:, None]  # lowering the pitch leaves the top bins empty
    lo = np.minimum(np.floor(src).astype(int), len(bins) - 1)
    frac = (src - lo)[:, None]
    hi = np.minimum(lo + 1, len(bins) - 1)

    def moved(a: np.ndarray) -> np.ndarray:
        return a[lo] * (1 - frac) + a[hi] * frac

    advance = moved(freq) * ratio
    advance[:, 0] = angle[np.rint(src).astype(int).clip(0, len(bins) - 1), 0]  # start from the source's phases
    phase = np.cumsum(advance, axis=1)
    _, y = istft(moved(np.abs(spec)) * inside * np.exp(1j * phase), nperseg=size, noverlap=size - hop)
    out = np.zeros_like(x)
    out[: min(len(x), len(y))] = y[: len(x)]
    return out


def telephone(x: np.ndarray) -> np.ndarray:
    """A telephone line's band: 300-3400 Hz."""
    sos = butter(8, TELEPHONE_HZ, btype="bandpass", fs=ANALYSIS_RATE, output="sos")
    return sosfilt(sos, x).astype(np.float32)


def reverb(x: np.ndarray, rt60: float, tail_db: float, seed: int) -> np.ndarray:
    """The voice in a room (``synth.room_response`` with no delay): the same level, a longer tail."""
    return fftconvolve(x, room_response(0.0, rt60, tail_db, ANALYSIS_RATE, seed))[: len(x)].astype(np.float32)


def noise(x: np.ndarray, rms: float, rng: np.random.Generator) -> np.ndarray:
    return x + rng.normal(0.0, rms, len(x)).astype(np.float32)


@dataclasses.dataclass(frozen=True)
class Augment:
    """Which kinds apply, each with chance ``probability`` per window."""

    kinds: tuple[str, ...]
    probability: float = 0.5

    def __call__(self, stereo: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
        """(n, 2) float32 audio changed, and what was done (kind: its parameters)."""
        x = np.array(stereo, np.float32)
        done: dict[str, Any] = {}
        for kind in KINDS:
            if kind in self.kinds and rng.random() < self.probability:
                x, done[kind] = _APPLY[kind](x, rng)
        return np.clip(x, -1.0, 1.0), done


def _speed(x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Any]:
    factor = float(rng.uniform(0.97, 1.03))
    return speed(x, factor), round(factor, 4)


def _per_channel(x: np.ndarray, rng: np.random.Generator, draw: Any, apply: Any) -> tuple[np.ndarray, Any]:
    params = [draw(rng) for _ in range(x.shape[1])]
    return np.stack([apply(x[:, c], p) for c, p in enumerate(params)], axis=1), params


def _pitch(x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Any]:
    return _per_channel(x, rng, lambda r: round(float(r.uniform(-3.0, 3.0)), 3), pitch)


def _reverb(x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Any]:
    def draw(r: np.random.Generator) -> tuple[float, float, int]:
        return round(float(r.uniform(0.15, 0.7)), 3), round(float(r.uniform(-12.0, -2.0)), 2), int(r.integers(2**31))

    return _per_channel(x, rng, draw, lambda c, p: reverb(c, *p))


def _bleed(x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Any]:
    db, delay, seed = float(rng.uniform(*BLEED_DB)), float(rng.uniform(1.0, 8.0)), int(rng.integers(2**31))
    a, b = add_bleed(x[:, 0], x[:, 1], db, delay, seed)
    return np.stack([a, b], axis=1), {"db": round(db, 2), "delay_ms": round(delay, 2)}


def _level(x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Any]:
    return _per_channel(x, rng, lambda r: round(float(r.uniform(-12.0, 6.0)), 2), level)


def _telephone(x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Any]:
    return np.stack([telephone(x[:, 0]), telephone(x[:, 1])], axis=1), list(TELEPHONE_HZ)


def _noise(x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Any]:
    """Noise 10-35 dB below the louder channel's RMS."""
    loud = float(np.sqrt(np.mean(x.astype(np.float64) ** 2, axis=0)).max())
    snr = float(rng.uniform(10.0, 35.0))
    rms = max(loud, 1e-4) * 10 ** (-snr / 20)
    return np.stack([noise(x[:, c], rms, rng) for c in range(x.shape[1])], axis=1), round(snr, 2)


_APPLY = {
    "speed": _speed,
    "pitch": _pitch,
    "reverb": _reverb,
    "bleed": _bleed,
    "level": _level,
    "telephone": _telephone,
    "noise": _noise,
}
