"""Real recorded voices for tests: Debian packages fetched by ``scripts/real_voices.sh`` (no media
in git), paired into a short two-voice dialogue by the corpus maker's own pairing
(``dialogues.converse`` with ``recordings.RecordedVoice``).

The dialogue's speakers are held out of every training corpus: LibriVox's reader of *Sense and
Sensibility* (pocketsphinx-testdata; public domain) as self and Asterisk's English prompt voice
(Allison Smith, asterisk-core-sounds-en-wav; CC-BY-SA-3.0) as the partner. A corpus that mixes in
real voices must leave ``HELD_OUT`` out.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
from pathlib import Path

import numpy as np

from convodrive.audio.source import DyadicAudio
from convodrive.corpus.dialogues import Dialogue, converse
from convodrive.corpus.recordings import RecordedVoice, scan_voices
from convodrive.eval.segments import Segments

REPO = Path(__file__).resolve().parents[1]
HELD_OUT = ("librivox/austen", "asterisk-en/allison")
SECONDS = 20.0


def cache_folder() -> Path:
    base = (
        os.environ.get("CONVODRIVE_REAL_VOICES")
        or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "convodrive" / "real_voices"
    )
    return Path(base)


def fetch() -> tuple[Path | None, str]:
    """The voices folder (``CACHE/voices``), fetched if missing; or None and why not."""
    voices = cache_folder() / "voices"
    if (voices / "INDEX.tsv").is_file():
        return voices, ""
    try:
        done = subprocess.run(
            [str(REPO / "scripts" / "real_voices.sh"), str(cache_folder())], capture_output=True, text=True, timeout=300
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"scripts/real_voices.sh failed ({exc.__class__.__name__})"
    if done.returncode != 0:
        return None, done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "scripts/real_voices.sh failed"
    return voices, ""


@dataclasses.dataclass(frozen=True)
class RealDialogue:
    audio: DyadicAudio
    truth: Segments
    dialogue: Dialogue
    voices: Path
    """The voices folder (a ``--voices`` folder per package)."""


def real_dialogue(voices: Path, seed: int = 4, seconds: float = SECONDS) -> RealDialogue:
    """About ``seconds`` of the two held-out speakers in conversation, with the true turns."""
    speakers = {s.name: s for folder in ("librivox", "asterisk-en") for s in scan_voices(voices / folder)}
    me, partner = (RecordedVoice(speakers[name], amp) for name, amp in zip(HELD_OUT, (0.6, 0.5)))
    dialogue = converse((me, partner), seconds, np.random.default_rng(seed))
    summary = dialogue.summary()["speech"]
    truth = Segments(
        tuple((a, b) for a, b in summary["self"]), tuple((a, b) for a, b in summary["partner"]), "real voices"
    )
    return RealDialogue(DyadicAudio(dialogue.audio[:, 0], dialogue.audio[:, 1]), truth, dialogue, voices)
