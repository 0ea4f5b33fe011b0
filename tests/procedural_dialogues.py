"""Dialogues for the procedural generator's tests, spoken by espeak-ng: several voices, rates and
turn patterns (alternating, self monologue, partner monologue, overlapping speech, a long
listening stretch, laughter). ``make`` writes each one's WAV and the JSON sidecar of its turns (the
reference speech segments), and ``with_bleed`` gives the same dialogue as microphones in one room
would record it."""

from __future__ import annotations

import json
from pathlib import Path

from convodrive.audio.source import AudioSource, DyadicAudio
from convodrive.audio.synth import PARTNER, SELF, Turn, add_bleed, synthesize_dialogue
from convodrive.eval.segments import Segments, load_segments

DIALOGUES: dict[str, list[Turn]] = {
    "alternating": [
        Turn(SELF, "Good morning. Did you manage to fix the camera on the robot?", "en-us", 160),
        Turn(PARTNER, "Mostly, yes. The focus still drifts when it gets warm.", "en-gb+f3", 175, gap=0.4),
        Turn(SELF, "Then we should add a small fan, or maybe move the lamp away.", "en-us", 160, gap=0.5),
        Turn(PARTNER, "Good idea. I will try that tomorrow.", "en-gb+f3", 175, gap=0.4),
    ],
    "self_monologue": [
        Turn(
            SELF,
            "Let me explain how the pipeline works. First the audio is analysed, then the "
            "generator picks a gesture for every stressed syllable, and finally the robot moves.",
            "en-gb",
            190,
            pitch=40,
        ),
    ],
    "partner_monologue": [
        Turn(
            PARTNER,
            "I have been thinking about the schedule for next week, and honestly I believe "
            "we can finish the tests on Tuesday if nothing else breaks.",
            "en-us+f2",
            150,
        ),
    ],
    "overlap": [
        Turn(SELF, "So the first thing I wanted to show you is the new head design.", "en-us+m3", 170),
        Turn(PARTNER, "Oh wait, is that the one with the bigger eyes?", "en-gb", 185, gap=-0.9),
        Turn(SELF, "Yes, exactly that one. It looks much friendlier now.", "en-us+m3", 170, gap=0.3),
    ],
    "story": [
        Turn(SELF, "How was the conference?", "en-us", 165),
        Turn(
            PARTNER,
            "It was long, but good. On the first day we set up the demo, and the robot would not "
            "start. We spent two hours on it. Then Anna found a loose cable, of all things.",
            "en-gb+f4",
            165,
            pitch=60,
            gap=0.5,
        ),
        Turn(SELF, "Oh no.", "en-us", 165, gap=0.4),
        Turn(
            PARTNER,
            "After that it went well. People loved the eyes, and one child talked to it for twenty "
            "minutes. We even got an invitation to a school in the spring.",
            "en-gb+f4",
            165,
            pitch=60,
            gap=0.4,
        ),
        Turn(SELF, "That is wonderful news.", "en-us", 165, gap=0.5),
    ],
    "laughter": [
        Turn(SELF, "Did the robot behave at the party?", "en-us", 165),
        Turn(
            PARTNER,
            "Not at all. It followed the cat around all evening and kept saying hello to it.",
            "en-us+f3",
            170,
            gap=0.5,
        ),
        Turn(PARTNER, "ha ha ha ha ha ha", "en-us+f3", 165, gap=0.3),
        Turn(PARTNER, "Then it fell asleep under the table.", "en-us+f3", 170, gap=0.4),
        Turn(SELF, "ha ha ha ha ha ha", "en-us", 165, gap=0.5),
        Turn(SELF, "That sounds like our robot.", "en-us", 165, gap=0.3),
    ],
}


def make(name: str, directory: Path) -> tuple[Path, DyadicAudio]:
    """The dialogue's WAV (made once per directory) and its audio; ``reference`` reads its turns."""
    path = directory / f"{name}.wav"
    if not path.exists():
        info = synthesize_dialogue(DIALOGUES[name], path, seed=3)
        path.with_suffix(".json").write_text(json.dumps(info.to_json(), indent=2))
    return path, AudioSource(path).read_all()


def reference(path: Path) -> Segments:
    """Who spoke when in a dialogue ``make`` wrote: its turns, from the JSON sidecar."""
    return load_segments(path.with_suffix(".json"))


def with_bleed(audio: DyadicAudio, level_db: float = -12.0) -> DyadicAudio:
    """The dialogue as two microphones in one room hear it: each speaker also ``level_db`` in the
    other's channel, 3 ms late, with a room's reverberant tail."""
    return DyadicAudio(*add_bleed(audio.self_voice, audio.other_voice, level_db), source=audio.source)
