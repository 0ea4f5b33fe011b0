"""Synthetic dyadic conversations with realistic turn taking, spoken by espeak-ng.

A conversation alternates the floor between self (channel 0) and the partner (channel 1). The
holder speaks one to a few sentences with pauses inside the turn; now and then a long monologue
gives the other a long listening stretch. The listener backchannels ("mm-hm", "yeah") near the
ends of the holder's sentences, sometimes over them. The floor changes hands after a gap, an
overlap (the next speaker starts before the last one finishes) or a long silence. Everything is
drawn from one seeded generator, so a seed gives the same conversation, sample for sample.
Who speaks is a source of utterances (``Utterances``): espeak-ng here, recorded utterances of
real speakers in ``corpus.recordings``; the timeline is the same for both.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np

from convodrive.audio.source import ANALYSIS_RATE
from convodrive.audio.synth import PARTNER, SELF, mix_voices, speak
from convodrive.corpus.phrases import BANKS


@dataclasses.dataclass(frozen=True)
class Voice:
    """An espeak-ng voice: language voice, variant (``m3``, ``f2``, ...), pitch 0-99, words per minute."""

    language: str
    variant: str
    pitch: int
    rate: int
    amplitude: float = 0.6

    @property
    def espeak(self) -> str:
        return f"{self.language}+{self.variant}"

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class TurnTaking:
    """How the floor moves; probabilities per sentence or per turn change."""

    sentences_per_turn: tuple[int, int] = (1, 3)
    monologue: float = 0.18
    """Chance that a turn is a long one (4 to 9 sentences): the other listens for a long stretch."""
    pause_in_turn: tuple[float, float] = (0.2, 0.9)
    backchannel: float = 0.3
    """Chance per sentence that the listener backchannels near its end."""
    overlap: float = 0.3
    long_silence: float = 0.1


@dataclasses.dataclass(frozen=True)
class Speech:
    channel: int
    start: float
    end: float
    kind: str
    """``sentence`` or ``backchannel``."""


@dataclasses.dataclass
class Dialogue:
    audio: np.ndarray
    """(n, 2) float32 at 16 kHz: self, partner."""
    speech: list[Speech]

    @property
    def duration(self) -> float:
        return len(self.audio) / ANALYSIS_RATE

    def summary(self) -> dict[str, Any]:
        """Counts and the speech segments per channel (seconds), for the corpus manifest."""
        sentences = [s for s in self.speech if s.kind == "sentence"]
        overlaps = sum(
            1
            for a, b in zip(sentences, sentences[1:])
            if a.channel != b.channel and b.start < a.end  # the next holder started before the last finished
        )
        return {
            "sentences": len(sentences),
            "backchannels": sum(1 for s in self.speech if s.kind == "backchannel"),
            "turn_overlaps": overlaps,
            "speech": {
                name: [[round(s.start, 2), round(s.end, 2)] for s in self.speech if s.channel == ch]
                for name, ch in (("self", SELF), ("partner", PARTNER))
            },
        }


class Utterances(Protocol):
    """Where a voice's utterances come from: ``pick`` draws what to say (a sentence or a
    backchannel), ``render`` makes its audio (float32 mono at 16 kHz, silence trimmed; empty: none).
    Two steps, so the timeline draws its numbers in one order whatever the source."""

    def pick(self, kind: str, rng: np.random.Generator) -> Any: ...

    def render(self, item: Any, rng: np.random.Generator) -> np.ndarray: ...

    @property
    def amplitude(self) -> float: ...


@dataclasses.dataclass(frozen=True)
class SpokenVoice:
    """An espeak-ng voice speaking its language's phrase bank."""

    voice: Voice

    @property
    def amplitude(self) -> float:
        return self.voice.amplitude

    def pick(self, kind: str, rng: np.random.Generator) -> str:
        bank = BANKS[self.voice.language]
        return bank.sentence(rng) if kind == "sentence" else bank.backchannel(rng)

    def render(self, item: str, rng: np.random.Generator) -> np.ndarray:
        rate = int(round(self.voice.rate * rng.uniform(0.92, 1.08)))
        return speak(item, self.voice.espeak, rate, self.voice.pitch, ANALYSIS_RATE)


def synthesize(
    voices: tuple[Voice, Voice], seconds: float, rng: np.random.Generator, style: TurnTaking | None = None
) -> Dialogue:
    """About ``seconds`` of conversation between ``voices`` (self, partner) in their language."""
    return converse((SpokenVoice(voices[0]), SpokenVoice(voices[1])), seconds, rng, style)


def converse(
    sources: tuple[Utterances, Utterances],
    seconds: float,
    rng: np.random.Generator,
    style: TurnTaking | None = None,
) -> Dialogue:
    """About ``seconds`` of conversation between ``sources`` (self, partner): the floor moves as
    ``style`` says, whoever speaks (espeak-ng voices or recorded utterances)."""
    style = style or TurnTaking()
    placed: list[tuple[int, int, np.ndarray]] = []
    speech: list[Speech] = []

    def say(channel: int, item: Any, start: float, kind: str, gain: float = 1.0) -> float:
        source = sources[channel]
        audio = source.render(item, rng)
        if len(audio) == 0:
            return start
        audio = audio * (gain * source.amplitude / max(float(np.abs(audio).max()), 1e-9))
        start = max(0.0, start)
        placed.append((channel, int(round(start * ANALYSIS_RATE)), audio.astype(np.float32)))
        end = start + len(audio) / ANALYSIS_RATE
        speech.append(Speech(channel, start, end, kind))
        return end

    t = float(rng.uniform(0.3, 1.0))
    holder = int(rng.integers(2))
    while t < seconds:
        listener = 1 - holder
        if rng.random() < style.monologue:
            count = int(rng.integers(4, 10))
        else:
            count = int(rng.integers(style.sentences_per_turn[0], style.sentences_per_turn[1] + 1))
        end = t
        for _ in range(count):
            end = say(holder, sources[holder].pick("sentence", rng), t, "sentence")
            if rng.random() < style.backchannel:
                item = sources[listener].pick("backchannel", rng)
                say(listener, item, end - rng.uniform(-0.35, 0.45), "backchannel", gain=0.7)
            t = end + rng.uniform(*style.pause_in_turn)
            if t >= seconds:
                break
        r = rng.random()
        if r < style.overlap:
            t = end - rng.uniform(0.15, 0.7)
        elif r < style.overlap + style.long_silence:
            t = end + rng.uniform(1.2, 3.0)
        else:
            t = end + rng.uniform(0.1, 0.8)
        holder = listener
    last = max(s.end for s in speech) if speech else seconds
    total = int(round((last + rng.uniform(0.3, 0.8)) * ANALYSIS_RATE))
    noise = float(rng.uniform(5e-4, 2e-3))
    audio = mix_voices(placed, total, seed=int(rng.integers(2**31)), noise_level=noise)
    return Dialogue(audio, sorted(speech, key=lambda s: s.start))
