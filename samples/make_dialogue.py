"""Make the bundled sample dialogue: samples/dialogue.wav and samples/dialogue.json.

Two espeak-ng voices take turns: self (channel 0, a low male en-us voice) and the partner
(channel 1, a higher female variant). Some turns leave a pause, some overlap (a negative gap), and
the partner backchannels once while self is talking. Run from anywhere:

    python samples/make_dialogue.py
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from convodrive.audio.synth import PARTNER, SELF, DialogueInfo, Turn, synthesize_dialogue
from convodrive.plumbing.atomic import write_text_atomic

HERE = Path(__file__).resolve().parent
SELF_VOICE = {"voice": "en-us", "pitch": 35, "rate": 160}
PARTNER_VOICE = {"voice": "en-us+f3", "pitch": 70, "rate": 175}


def dialogue_turns() -> list[Turn]:
    s = lambda text, **kw: Turn(SELF, text, **{**SELF_VOICE, **kw})  # noqa: E731
    p = lambda text, **kw: Turn(PARTNER, text, **{**PARTNER_VOICE, **kw})  # noqa: E731
    return [
        s("Hi there. Did you get a chance to look at the robot head yesterday?"),
        p("I did. It was moving its eyes really smoothly.", gap=0.5),
        s("Great. I changed the gaze model so it looks away while it is thinking.", gap=0.25),
        p("Right.", start=None, gap=-1.6),  # a backchannel while self is still talking
        p("That sounds much more natural. What about the mouth?", gap=0.9),
        s("The jaw follows the voice now, but the lips are still a bit stiff.", gap=-0.35),
        p("Maybe we can use the visemes from the speech recogniser.", gap=0.6),
        s("Yes, let us try that tomorrow.", gap=0.3),
    ]


def make_dialogue(
    turns: Sequence[Turn] | None = None, out_wav: Path = HERE / "dialogue.wav", sample_rate: int = 16000, seed: int = 7
) -> DialogueInfo:
    """Write the WAV (the bundled turns by default) and its JSON sidecar: each turn's speaker, start, end, text."""
    info = synthesize_dialogue(turns or dialogue_turns(), out_wav, sample_rate=sample_rate, seed=seed)
    write_text_atomic(Path(out_wav).with_suffix(".json"), json.dumps(info.to_json(), indent=2) + "\n")
    return info


if __name__ == "__main__":
    info = make_dialogue()
    print(f"{info.path}: {info.duration:.1f} s, {len(info.turns)} turns")
