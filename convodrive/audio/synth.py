"""Synthetic two-speaker dialogues from espeak-ng, for the bundled sample and for tests.

A dialogue is a list of turns, each spoken by self (channel 0) or the partner (channel 1) in an
espeak-ng voice at a rate and pitch; a turn starts at a given time, or a gap after the previous
turn ends (a negative gap makes the two overlap). The result is a stereo 16-bit WAV, written
atomically, and the measured start and end of each turn's speech, so tests know the ground truth.
``add_bleed`` makes each microphone hear the other speaker as in a shared room.
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
import soundfile as sf
from scipy.signal import fftconvolve, resample_poly

from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.errors import UserError

SELF, PARTNER = 0, 1


@dataclasses.dataclass(frozen=True)
class Turn:
    """One utterance. ``start`` in seconds, or None: ``gap`` seconds after the previous turn ends."""

    speaker: int
    text: str
    voice: str = "en-us"
    rate: int = 165
    """Words per minute (espeak-ng ``-s``)."""
    pitch: int = 50
    """0..99 (espeak-ng ``-p``)."""
    start: float | None = None
    gap: float = 0.3
    amplitude: float = 0.6
    """Peak level of the turn, as a fraction of full scale."""


@dataclasses.dataclass(frozen=True)
class TurnTiming:
    speaker: int
    text: str
    voice: str
    rate: int
    start: float
    end: float


@dataclasses.dataclass(frozen=True)
class DialogueInfo:
    path: Path
    sample_rate: int
    duration: float
    turns: tuple[TurnTiming, ...]

    def to_json(self) -> dict:
        return {
            "audio": self.path.name,
            "sample_rate": self.sample_rate,
            "duration": round(self.duration, 3),
            "channels": {"0": "self", "1": "partner"},
            "turns": [
                {
                    "speaker": "self" if t.speaker == SELF else "partner",
                    "channel": t.speaker,
                    "start": round(t.start, 3),
                    "end": round(t.end, 3),
                    "text": t.text,
                    "voice": t.voice,
                    "rate": t.rate,
                }
                for t in self.turns
            ],
        }


def speak(text: str, voice: str = "en-us", rate: int = 165, pitch: int = 50, sample_rate: int = 16000) -> np.ndarray:
    """One utterance as float32 mono at ``sample_rate``, leading and trailing silence trimmed."""
    exe = shutil.which("espeak-ng")
    if exe is None:
        raise UserError("espeak-ng is not installed; it is needed to synthesise speech (e.g. apt install espeak-ng)")
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "turn.wav"
        result = subprocess.run(
            [exe, "-v", voice, "-s", str(rate), "-p", str(pitch), "-w", str(wav), "--", text],
            capture_output=True,
            text=True,
            timeout=60,
        )
        if result.returncode != 0 or not wav.exists():
            raise UserError(f"espeak-ng failed for voice {voice!r}: {result.stderr.strip() or result.returncode}")
        audio, rate_in = sf.read(wav, dtype="float32")
    if audio.ndim > 1:
        audio = audio.mean(axis=1)
    if rate_in != sample_rate:
        ratio = Fraction(sample_rate, rate_in)
        audio = resample_poly(audio, ratio.numerator, ratio.denominator).astype(np.float32)
    return trim_silence(audio)


def trim_silence(audio: np.ndarray) -> np.ndarray:
    """``audio`` without its leading and trailing stretch below 2 % of its peak."""
    loud = np.flatnonzero(np.abs(audio) > 0.02 * max(float(np.abs(audio).max(initial=0.0)), 1e-9))
    return audio[loud[0] : loud[-1] + 1] if len(loud) else audio[:0]


def synthesize_dialogue(
    turns: Sequence[Turn],
    path: str | Path,
    sample_rate: int = 16000,
    seed: int = 0,
    noise_level: float = 1e-3,
    lead_in: float = 0.5,
    tail: float = 0.5,
) -> DialogueInfo:
    """Speak ``turns`` onto channel 0 (self) and 1 (partner) and write a stereo 16-bit WAV.

    ``noise_level`` adds a faint seeded noise floor (RMS, full scale 1) so silence is not digital
    zero, as in a real recording; 0 turns it off.
    """
    if not turns:
        raise ValueError("a dialogue needs at least one turn")
    clips, timings = [], []
    cursor = lead_in
    for turn in turns:
        if turn.speaker not in (SELF, PARTNER):
            raise ValueError(f"turn speaker must be 0 (self) or 1 (partner), got {turn.speaker}")
        audio = speak(turn.text, turn.voice, turn.rate, turn.pitch, sample_rate)
        audio = audio * (turn.amplitude / max(float(np.abs(audio).max()), 1e-9))
        start = turn.start if turn.start is not None else max(0.0, cursor + turn.gap)
        end = start + len(audio) / sample_rate
        clips.append((turn.speaker, int(round(start * sample_rate)), audio))
        timings.append(TurnTiming(turn.speaker, turn.text, turn.voice, turn.rate, start, end))
        cursor = end
    total = int(round((max(t.end for t in timings) + tail) * sample_rate))
    stereo = mix_voices(clips, total, seed=seed, noise_level=noise_level)
    path = Path(path)
    with atomic_path(path) as tmp:
        sf.write(tmp, stereo, sample_rate, subtype="PCM_16", format="WAV")
    return DialogueInfo(path, sample_rate, total / sample_rate, tuple(timings))


def room_response(
    delay_ms: float = 3.0, rt60: float = 0.25, tail_db: float = -5.0, sample_rate: int = 16000, seed: int = 0
) -> np.ndarray:
    """Impulse response from a speaker to the other person's microphone: the direct sound
    ``delay_ms`` late, then a diffuse tail (seeded noise decaying by 60 dB in ``rt60`` seconds)
    ``tail_db`` below it in energy. Unit energy overall."""
    rng = np.random.default_rng(seed)
    d = int(round(delay_ms * sample_rate / 1000))
    gap = int(0.0025 * sample_rate)  # the first reflections arrive a few ms after the direct sound
    t = np.arange(int(rt60 * sample_rate)) / sample_rate
    tail = rng.standard_normal(len(t)) * np.exp(-6.9 * t / rt60)
    h = np.zeros(d + gap + len(t))
    h[d] = 1.0
    h[d + gap :] += tail * np.sqrt(10 ** (tail_db / 10) / np.sum(tail**2))
    return h / np.sqrt(np.sum(h**2))


def add_bleed(
    self_voice: np.ndarray, other_voice: np.ndarray, level_db: float = -12.0, delay_ms: float = 3.0, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Both channels as microphones in one room hear them: each also picks up the other speaker
    ``level_db`` below that speaker's own microphone, through ``room_response``."""
    gain = 10 ** (level_db / 20)
    n = len(self_voice)
    into_self = fftconvolve(other_voice, room_response(delay_ms, seed=seed))[:n]
    into_other = fftconvolve(self_voice, room_response(delay_ms, seed=seed + 1))[:n]
    return (
        np.clip(self_voice + gain * into_self, -1, 1).astype(np.float32),
        np.clip(other_voice + gain * into_other, -1, 1).astype(np.float32),
    )


def mix_voices(
    placed: Sequence[tuple[int, int, np.ndarray]], num_samples: int, seed: int = 0, noise_level: float = 1e-3
) -> np.ndarray:
    """(num_samples, 2) float32 in [-1, 1]: each ``(channel, offset, audio)`` added at its sample
    offset (cut at the end), plus a seeded noise floor of RMS ``noise_level`` (0: none)."""
    stereo = np.zeros((num_samples, 2), np.float32)
    for channel, offset, audio in placed:
        piece = audio[: max(0, num_samples - offset)]
        stereo[offset : offset + len(piece), channel] += piece
    if noise_level > 0:
        stereo += np.random.default_rng(seed).normal(0.0, noise_level, stereo.shape).astype(np.float32)
    return np.clip(stereo, -1.0, 1.0)
