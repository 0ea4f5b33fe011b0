"""The bootstrap corpus: synthetic conversations, motion from a teacher generator (the procedural one).

Each conversation is planned from ``(seed, index)`` alone: a language, a "speaker" (the person on
channel 0: a voice and a motion style, carried as the speaker label), a partner voice and a length.
It is spoken by espeak-ng with realistic turn taking (``dialogues``), and the teacher makes
``takes`` takes of self's motion from it (different seeds: the one-to-many structure the models
learn). The teacher is handed in (``convodrive corpus make`` hands the procedural generator's
class), since generators sit a layer above the corpus (docs/ARCHITECTURE.md). Conversations are made in worker processes and written in order by one
``CorpusWriter``, so the corpus depends on the seed only, never on the number of jobs.

Speech the user has joins the espeak-ng conversations (``corpus.recordings``): recorded voices
paired by the same timeline (``PairPlan``) and two-channel recordings as they are
(``RecordedPlan``); the teacher labels them all alike. The manifest's source lists each source
with its licence and the hours of conversation it speaks in.
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from convodrive.audio.source import DyadicAudio
from convodrive.corpus.dialogues import TurnTaking, Voice, converse, synthesize
from convodrive.corpus.manifest import safe_id
from convodrive.corpus.recordings import (
    RecordedConversation,
    RecordedSpeaker,
    RecordedVoice,
    read_conversation,
    recorded_turns,
)
from convodrive.corpus.writer import CorpusWriter, Prepared, Recording, prepare, quantise
from convodrive.motion.clip import MotionClip
from convodrive.plumbing.errors import UserError

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
    stratum: ClassVar[str] = "synthesised"

    @property
    def id(self) -> str:
        return f"conv{self.index:05d}"

    @property
    def sources(self) -> tuple[str, ...]:
        return (ESPEAK,)

    def conversation(self) -> tuple[np.ndarray, dict[str, Any]]:
        """The conversation's audio (n, 2) and what the manifest says of it."""
        rng = np.random.default_rng(self.seed)
        dialogue = synthesize((self.self_voice, self.partner_voice), self.seconds, rng, TurnTaking())
        voices = {"self": self.self_voice.to_json(), "partner": self.partner_voice.to_json()}
        return dialogue.audio, {"voices": voices, **dialogue.summary()}


@dataclasses.dataclass(frozen=True)
class PairPlan:
    """Two recorded speakers in a dialogue, timed as the espeak-ng conversations are."""

    index: int
    seconds: float
    speaker: Speaker
    self_voice: RecordedVoice
    partner_voice: RecordedVoice
    seed: int
    stratum: ClassVar[str] = "paired"

    @property
    def id(self) -> str:
        return f"pair{self.index:05d}"

    @property
    def language(self) -> str:
        return self.self_voice.speaker.source.language

    @property
    def sources(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(v.speaker.source.name for v in (self.self_voice, self.partner_voice)))

    def conversation(self) -> tuple[np.ndarray, dict[str, Any]]:
        rng = np.random.default_rng(self.seed)
        dialogue = converse((self.self_voice, self.partner_voice), self.seconds, rng, TurnTaking())
        voices = {
            "self": {"speaker": self.self_voice.speaker.name, "amplitude": self.self_voice.amplitude},
            "partner": {"speaker": self.partner_voice.speaker.name, "amplitude": self.partner_voice.amplitude},
        }
        return dialogue.audio, {"voices": voices, **dialogue.summary()}


@dataclasses.dataclass(frozen=True)
class RecordedPlan:
    """A two-channel recording taken as it is; its turns from its segments or voice activity."""

    index: int
    recording: RecordedConversation
    speaker: Speaker
    seed: int
    stratum: ClassVar[str] = "recorded"

    @property
    def id(self) -> str:
        return safe_id(f"rec{self.index:05d}-{self.recording.path.stem}")

    @property
    def language(self) -> str:
        return self.recording.source.language

    @property
    def sources(self) -> tuple[str, ...]:
        return (self.recording.source.name,)

    def conversation(self) -> tuple[np.ndarray, dict[str, Any]]:
        audio = read_conversation(self.recording.path)
        speech, how = recorded_turns(self.recording, audio)
        stereo = np.stack([audio.self_voice, audio.other_voice], axis=1)
        return stereo, {"recording": self.recording.path.name, "turns_from": how, "speech": speech}


Plan = ConversationPlan | PairPlan | RecordedPlan
ESPEAK = "espeak-ng"


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


def make_conversation(plan: Plan, takes: int, teacher: Teacher) -> Prepared:
    """Make one planned conversation's audio, make its takes, and prepare it for the writer."""
    audio, described = plan.conversation()
    audio = quantise(audio)  # the teacher hears the 16-bit audio the corpus stores
    # The teacher's options in full (its phone decoder only knows English), so that eval compare
    # can score the teacher as it taught.
    style = {**plan.speaker.style, "phones": plan.language.startswith("en")}
    clips = teacher(style).generate(DyadicAudio(audio[:, 0], audio[:, 1]), seed=plan.seed, num_samples=takes)
    metadata = {
        "language": plan.language,
        "sources": list(plan.sources),
        "style": style,
        "take_seeds": [int(c.metadata["seed"]) for c in clips],
        **described,
    }
    return prepare(Recording(plan.id, audio, clips, plan.speaker.label, metadata=metadata, stratum=plan.stratum))


def plan_pairs(speakers: Sequence[RecordedSpeaker], hours: float, seed: int) -> list[PairPlan]:
    """Dialogues of two different recorded speakers until they add up to ``hours``; each drawn
    from ``(seed, index)`` (a stream apart from the espeak-ng plans')."""
    if len(speakers) < 2:
        raise UserError("recorded voices: pairing needs at least two speakers (speaker folders) in all")
    plans: list[PairPlan] = []
    remaining = hours * 3600.0
    while remaining > 0:
        i = len(plans)
        rng = np.random.default_rng([seed, 1, i])
        seconds = max(MIN_SECONDS, min(float(rng.uniform(*CONVERSATION_SECONDS)), remaining))
        a, b = rng.choice(len(speakers), size=2, replace=False)
        style = SPEAKERS[int(rng.integers(len(SPEAKERS)))]
        me = RecordedVoice(speakers[int(a)], float(rng.uniform(0.45, 0.7)))
        partner = RecordedVoice(speakers[int(b)], float(rng.uniform(0.35, 0.7)))
        plans.append(PairPlan(i, seconds, style, me, partner, int(rng.integers(2**31))))
        remaining -= seconds
    return plans


def plan_recorded(recordings: Sequence[RecordedConversation], seed: int) -> list[RecordedPlan]:
    """Each recording once, with a motion style drawn from ``(seed, index)``."""
    plans = []
    for i, rec in enumerate(recordings):
        rng = np.random.default_rng([seed, 2, i])
        plans.append(RecordedPlan(i, rec, SPEAKERS[int(rng.integers(len(SPEAKERS)))], int(rng.integers(2**31))))
    return plans


def _work(job: tuple[Plan, int, Teacher]) -> Prepared:
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


@dataclasses.dataclass(frozen=True)
class Recorded:
    """Speech the user has, for ``make_corpus``: recorded speakers to pair into ``voice_hours`` of
    dialogue, and two-channel recordings to take as they are."""

    speakers: Sequence[RecordedSpeaker] = ()
    voice_hours: float = 0.0
    conversations: Sequence[RecordedConversation] = ()

    def plans(self, seed: int) -> list[Plan]:
        pairs: list[Plan] = list(plan_pairs(self.speakers, self.voice_hours, seed)) if self.speakers else []
        return pairs + list(plan_recorded(self.conversations, seed))

    def licences(self) -> dict[str, str]:
        """Each source's name and licence."""
        found = [s.source for s in self.speakers] + [c.source for c in self.conversations]
        return {s.name: s.licence for s in found}


def make_corpus(
    hours: float,
    out: str | Path,
    teacher: Teacher,
    seed: int = 0,
    jobs: int | None = None,
    takes: int = 4,
    progress: Callable[[int, int], None] | None = None,
    recorded: Recorded | None = None,
) -> MakeReport:
    """Make ``hours`` of espeak-ng corpus (and the ``recorded`` speech's) in ``out`` (a new or
    empty folder) with ``jobs`` worker processes, motion by ``teacher`` (a class the workers can
    unpickle by name)."""
    jobs = jobs or default_jobs()
    recorded = recorded or Recorded()
    plans: list[Plan] = [*plan_corpus(hours, seed), *recorded.plans(seed)]
    if not plans:
        raise UserError("corpus make: nothing to make (give --hours above 0, --voices or --conversations)")
    licences = {ESPEAK: LICENCE, **recorded.licences()} if hours > 0 else recorded.licences()
    load_before = os.getloadavg()
    start = time.perf_counter()
    source: dict[str, Any] = {"kind": "made", "hours": hours, "seed": seed, "takes": takes, "generator": teacher.name}
    if recorded.speakers or recorded.conversations:
        source["voice_hours"] = recorded.voice_hours
    frames = 0
    per_source = dict.fromkeys(licences, 0)
    licence = LICENCE if list(licences) == [ESPEAK] else "; ".join(f"{k}: {v}" for k, v in licences.items())
    with CorpusWriter(out, source, seed=seed, licence=licence) as writer, contextlib.ExitStack() as stack:
        work = [(p, takes, teacher) for p in plans]
        if jobs == 1:
            results: Iterator[Prepared] = map(_work, work)
        else:
            # spawn: workers start clean (no inherited decoder or thread state from the parent).
            pool = stack.enter_context(multiprocessing.get_context("spawn").Pool(min(jobs, len(plans))))
            results = pool.imap(_work, work)
        for i, (plan, prepared) in enumerate(zip(plans, results), 1):
            writer.add(prepared)
            n = prepared.arrays[f"{prepared.recording.id}/mel"].shape[0]
            frames += n
            for name in plan.sources:
                per_source[name] += n
            if progress:
                progress(i, len(plans))
        writer.source["sources"] = [
            {"name": k, "licence": v, "hours": round(per_source[k] / 30.0 / 3600.0, 4)} for k, v in licences.items()
        ]
    return MakeReport(
        Path(out), len(plans), frames / 30.0 / 3600.0, time.perf_counter() - start, jobs, load_before, os.getloadavg()
    )
