"""The bootstrap corpus: synthetic conversations, motion from a teacher generator (the procedural one).

Each conversation is planned from ``(seed, index)`` alone: a language, a "speaker" (the person on
channel 0: a voice and a motion style, carried as the speaker label), a partner voice and a length.
It is spoken by espeak-ng with realistic turn taking (``dialogues``), and the teacher makes
``takes`` takes of self's motion from it (different seeds: the one-to-many structure the models
learn). The teacher is handed in (``convodrive corpus make`` hands the procedural generator's
class), since generators sit a layer above the corpus (docs/ARCHITECTURE.md). Conversations are made in worker processes and written in order by one
``CorpusWriter``, so the corpus depends on the seed only, never on the number of jobs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from convodrive.audio.source import DyadicAudio
from convodrive.corpus.dialogues import TurnTaking, Voice, synthesize
from convodrive.corpus.writer import CorpusWriter, Prepared, Recording, prepare, quantise
from convodrive.motion.clip import MotionClip

LICENCE = "no third-party data: speech synthesised by espeak-ng, motion by convodrive's procedural generator"
CONVERSATION_SECONDS = (60.0, 150.0)


class _Takes(Protocol):
    def generate(self, audio: DyadicAudio, seed: int = 0, num_samples: int = 1) -> Sequence[MotionClip]: ...


class Teacher(Protocol):
    """A generator class: made from a speaker's style (its options), it makes the takes; the
    corpus's manifest records its name."""

    name: str

    def __call__(self, options: Mapping[str, Any]) -> _Takes: ...


MIN_SECONDS = 8.0


@dataclasses.dataclass(frozen=True)
class Speaker:
    """A person on channel 0: their voice and their motion style (procedural generator options)."""

    label: str
    style: dict[str, Any]
    variant: str
    pitch: int
    rate: int


def _style(
    expressiveness: float, variability: float, gestures: bool, gaze_aversion: float, gaze_range: float
) -> dict[str, Any]:
    """A speaker's procedural generator options."""
    return {
        "expressiveness": expressiveness,
        "variability": variability,
        "gestures": gestures,
        "gaze_aversion": gaze_aversion,
        "gaze_range": gaze_range,
    }


SPEAKERS: tuple[Speaker, ...] = (
    Speaker("calm", _style(0.6, 0.6, False, gaze_aversion=0.8, gaze_range=0.8), "m3", 35, 150),
    Speaker("animated", _style(1.7, 1.3, True, gaze_aversion=1.5, gaze_range=1.3), "f2", 65, 185),
    Speaker("reserved", _style(0.35, 1.0, False, gaze_aversion=1.8, gaze_range=0.6), "f4", 55, 160),
    Speaker("restless", _style(1.2, 2.2, True, gaze_aversion=2.2, gaze_range=1.5), "m6", 45, 175),
    Speaker("steady", _style(1.0, 0.3, True, gaze_aversion=0.4, gaze_range=0.8), "m1", 40, 165),
    Speaker("expansive", _style(2.0, 1.0, True, gaze_aversion=1.0, gaze_range=1.6), "f5", 70, 170),
)
"""The speaker styles, each with a voice: how much they move, how alike their takes are, whether they
gesture, and how they look at the partner (the reserved look away often but not far, the steady
hold their gaze, the restless and the expansive look far away)."""

PARTNER_VARIANTS = ("m2", "m4", "m5", "m7", "f1", "f3", "klatt", "klatt4", "steph", "david", "annie", "andy")
LANGUAGES: tuple[tuple[str, float], ...] = (
    ("en-us", 0.40),
    ("en-gb", 0.12),
    ("de", 0.12),
    ("fr-fr", 0.12),
    ("es", 0.12),
    ("it", 0.12),
)


@dataclasses.dataclass(frozen=True)
class ConversationPlan:
    index: int
    seconds: float
    language: str
    speaker: Speaker
    self_voice: Voice
    partner_voice: Voice
    seed: int

    @property
    def id(self) -> str:
        return f"conv{self.index:05d}"


def plan_corpus(hours: float, seed: int) -> list[ConversationPlan]:
    """Conversations until their lengths add up to ``hours``; each drawn from ``(seed, index)``."""
    plans: list[ConversationPlan] = []
    remaining = hours * 3600.0
    while remaining > 0:
        i = len(plans)
        rng = np.random.default_rng([seed, i])
        seconds = max(MIN_SECONDS, min(float(rng.uniform(*CONVERSATION_SECONDS)), remaining))
        language = str(rng.choice([lang for lang, _ in LANGUAGES], p=[p for _, p in LANGUAGES]))
        speaker = SPEAKERS[int(rng.integers(len(SPEAKERS)))]
        self_voice = Voice(
            language,
            speaker.variant,
            int(np.clip(speaker.pitch + rng.integers(-6, 7), 0, 99)),
            int(speaker.rate + rng.integers(-10, 11)),
            float(rng.uniform(0.45, 0.7)),
        )
        partner_voice = Voice(
            language,
            str(rng.choice(PARTNER_VARIANTS)),
            int(rng.integers(20, 80)),
            int(rng.integers(135, 195)),
            float(rng.uniform(0.35, 0.7)),
        )
        plans.append(
            ConversationPlan(i, seconds, language, speaker, self_voice, partner_voice, int(rng.integers(2**31)))
        )
        remaining -= seconds
    return plans


def make_conversation(plan: ConversationPlan, takes: int, teacher: Teacher) -> Prepared:
    """Speak one planned conversation, make its takes, and prepare it for the writer."""
    rng = np.random.default_rng(plan.seed)
    dialogue = synthesize((plan.self_voice, plan.partner_voice), plan.seconds, rng, TurnTaking())
    audio = quantise(dialogue.audio)  # the teacher hears the 16-bit audio the corpus stores
    english = plan.language.startswith("en")
    # The teacher's options in full (its phone decoder only knows English), so that eval compare
    # can score the teacher as it taught.
    style = {**plan.speaker.style, "phones": english}
    clips = teacher(style).generate(DyadicAudio(audio[:, 0], audio[:, 1]), seed=plan.seed, num_samples=takes)
    metadata = {
        "language": plan.language,
        "voices": {"self": plan.self_voice.to_json(), "partner": plan.partner_voice.to_json()},
        "style": style,
        "take_seeds": [int(c.metadata["seed"]) for c in clips],
        **dialogue.summary(),
    }
    return prepare(Recording(plan.id, audio, clips, plan.speaker.label, metadata=metadata))


def _work(job: tuple[ConversationPlan, int, Teacher]) -> Prepared:
    return make_conversation(*job)


@dataclasses.dataclass(frozen=True)
class MakeReport:
    folder: Path
    conversations: int
    hours: float
    seconds: float
    jobs: int
    load_before: tuple[float, float, float]
    load_after: tuple[float, float, float]

    def to_json(self) -> dict[str, Any]:
        return {
            "corpus": str(self.folder),
            "conversations": self.conversations,
            "hours": round(self.hours, 4),
            "seconds": round(self.seconds, 1),
            "minutes_per_corpus_hour": round(self.seconds / 60.0 / max(self.hours, 1e-9), 2),
            "jobs": self.jobs,
            "loadavg_before": [round(v, 2) for v in self.load_before],
            "loadavg_after": [round(v, 2) for v in self.load_after],
        }


def default_jobs() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def make_corpus(
    hours: float,
    out: str | Path,
    teacher: Teacher,
    seed: int = 0,
    jobs: int | None = None,
    takes: int = 4,
    progress: Callable[[int, int], None] | None = None,
) -> MakeReport:
    """Make ``hours`` of corpus in ``out`` (a new or empty folder) with ``jobs`` worker processes,
    motion by ``teacher`` (a class the workers can unpickle by name)."""
    jobs = jobs or default_jobs()
    plans = plan_corpus(hours, seed)
    load_before = os.getloadavg()
    start = time.perf_counter()
    source = {"kind": "made", "hours": hours, "seed": seed, "takes": takes, "generator": teacher.name}
    frames = 0
    with CorpusWriter(out, source, seed=seed, licence=LICENCE) as writer, contextlib.ExitStack() as stack:
        work = [(p, takes, teacher) for p in plans]
        if jobs == 1:
            results: Iterator[Prepared] = map(_work, work)
        else:
            # spawn: workers start clean (no inherited decoder or thread state from the parent).
            pool = stack.enter_context(multiprocessing.get_context("spawn").Pool(min(jobs, len(plans))))
            results = pool.imap(_work, work)
        for i, prepared in enumerate(results, 1):
            writer.add(prepared)
            frames += prepared.arrays[f"{prepared.recording.id}/mel"].shape[0]
            if progress:
                progress(i, len(plans))
    return MakeReport(
        Path(out), len(plans), frames / 30.0 / 3600.0, time.perf_counter() - start, jobs, load_before, os.getloadavg()
    )
