"""Dialogues for the procedural generator's tests, spoken by espeak-ng: several voices, rates and
turn patterns (alternating, self monologue, partner monologue, overlapping speech)."""

from __future__ import annotations

from pathlib import Path

from convodrive.audio.source import AudioSource, DyadicAudio
from convodrive.audio.synth import PARTNER, SELF, Turn, synthesize_dialogue

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
}


def make(name: str, directory: Path) -> tuple[Path, DyadicAudio]:
    path = directory / f"{name}.wav"
    if not path.exists():
        synthesize_dialogue(DIALOGUES[name], path, seed=3)
    return path, AudioSource(path).read_all()
