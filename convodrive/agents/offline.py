"""Stand-ins that let a voice agent run with no network and no keys (the examples, tests, demos).

- ``partner_audio``: the user from one channel of a sound file (in place of a microphone or a
  room's track);
- ``TurnDetector``: the user's speech and turn ends from the audio's level (in place of a VAD and
  an end-of-turn model);
- ``ScriptedReplies``: a line per user turn (in place of an LLM);
- ``synthesize``: speech from espeak-ng (in place of a TTS service);
- ``agent_parser`` / ``open_session`` / ``finish``: the examples' command line, the session it
  opens, and after it, the played voice muxed into the avatar video (``render``).

Nothing here imports a framework.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import soundfile as sf

from convodrive.audio.source import ANALYSIS_RATE, AudioSource, ChannelMap
from convodrive.audio.synth import speak
from convodrive.pipeline.session import LiveSession
from convodrive.plumbing.errors import EXIT_USER_ERROR, OneLineParser, UserError, error_line
from convodrive.plumbing.safe_yaml import parse_scalar

LINES = (
    "That sounds good to me.",
    "Really? Tell me more about it.",
    "I see. And what happened next?",
    "Let me think about that for a moment.",
)
BLOCK = 0.02
"""Seconds of partner audio per block, as a microphone delivers it."""


def partner_audio(path: str | Path, channel: int) -> np.ndarray:
    """One channel of ``path`` at ``ANALYSIS_RATE`` as int16 (a ``UserError`` names a bad file)."""
    audio = AudioSource(path, ChannelMap(self_channel=channel, other_channel=None)).read_all().self_voice
    return (np.clip(audio, -1.0, 1.0) * 32767).astype(np.int16)


def synthesize(text: str, rate: int = ANALYSIS_RATE) -> np.ndarray:
    """``text`` spoken by espeak-ng, int16 at ``rate``."""
    return (np.clip(speak(text, sample_rate=rate), -1.0, 1.0) * 32767).astype(np.int16)


class TurnDetector:
    """Speech from the level of 20 ms blocks; the turn ends after ``hangover`` seconds of quiet."""

    def __init__(self, threshold_db: float = -38.0, start: float = 0.1, hangover: float = 0.6) -> None:
        self.threshold = 10.0 ** (threshold_db / 20.0) * 32768.0
        self.start_blocks = max(int(round(start / BLOCK)), 1)
        self.end_blocks = max(int(round(hangover / BLOCK)), 1)
        self.speaking = False
        self._loud = 0
        self._quiet = 0

    def push(self, block: np.ndarray) -> str | None:
        """``start`` when speech began, ``end`` when the turn ended, else None."""
        loud = float(np.sqrt(np.mean(block.astype(np.float64) ** 2))) > self.threshold
        self._loud, self._quiet = (self._loud + 1, 0) if loud else (0, self._quiet + 1)
        if not self.speaking and self._loud >= self.start_blocks:
            self.speaking = True
            return "start"
        if self.speaking and self._quiet >= self.end_blocks:
            self.speaking = False
            return "end"
        return None


class ScriptedReplies:
    """The next of ``lines`` for each user turn, round and round."""

    def __init__(self, lines: tuple[str, ...] = LINES) -> None:
        self.lines = lines
        self.turns = 0

    def reply(self) -> str:
        line = self.lines[self.turns % len(self.lines)]
        self.turns += 1
        return line


def _names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected one or more names separated by commas")
    return names


def _backend_option(text: str) -> tuple[str, str, Any]:
    """``BACKEND.KEY=VALUE``, VALUE read as YAML (as ``convodrive live -B``)."""
    scoped, sep, raw = text.partition("=")
    backend, dot, key = scoped.partition(".")
    if not sep or not dot or not backend.strip() or not key.strip():
        raise argparse.ArgumentTypeError(f"expected BACKEND.KEY=VALUE (e.g. dynamixel.port=/dev/pts/3), got {text!r}")
    return backend.strip(), key.strip(), parse_scalar(raw)


def agent_parser(description: str) -> argparse.ArgumentParser:
    from convodrive.samples import bundled_dialogue

    p = OneLineParser(description=description)
    p.add_argument("--backend", type=_names, default=("record",), help="backends, comma-separated (default: record)")
    p.add_argument("-B", "--backend-option", type=_backend_option, action="append", default=[], metavar="B.KEY=V")
    p.add_argument("--partner", type=Path, default=bundled_dialogue(), help="the user's audio (default: the sample)")
    p.add_argument("--channel", type=int, default=1, help="the user's channel in --partner (default: 1)")
    p.add_argument("--seconds", type=float, default=None, help="how long to run (default: --partner's length + 3 s)")
    p.add_argument("--speaker", default="virtual", help="output device for the voice, or virtual (default)")
    p.add_argument("--out", type=Path, default=Path("convodrive-out"), help="output folder")
    return p


def open_session(args: argparse.Namespace, **request: Any) -> LiveSession:
    """A player-mode session for the parsed ``agent_parser`` arguments."""
    options: dict[str, dict[str, Any]] = {}
    for backend, key, value in args.backend_option:
        options.setdefault(backend, {})[key] = value
    return LiveSession.open(
        mode="player",
        backends=tuple(args.backend),
        backend_options=options,
        speaker=args.speaker,
        out_dir=args.out,
        **request,
    )


def finish(live: LiveSession, out_dir: Path) -> None:
    """After ``close``: the voice the speaker played as ``voice.wav``, and muxed into the avatar
    video when ``render`` made one (the session has no audio file for it to mux itself)."""
    speaker = live.speaker
    if speaker is None or not hasattr(speaker, "samples"):
        return
    wav = out_dir / "voice.wav"
    sf.write(wav, speaker.samples(), speaker.rate)
    video = out_dir / "avatar.mp4"
    if not video.exists():
        return
    from convodrive.plumbing.video import ffmpeg_exe

    tmp = video.with_name("avatar.voice.mp4")
    command = [ffmpeg_exe(), "-y", "-loglevel", "error", "-i", str(video), "-i", str(wav)]
    command += ["-map", "0:v", "-map", "1:a", "-c:v", "copy", "-c:a", "aac", "-shortest", str(tmp)]
    subprocess.run(command, check=True, capture_output=True)
    os.replace(tmp, video)


def run_main(main: Callable[[list[str] | None], object]) -> int:
    """An example's entry point: a bad file or option is one line on stderr and exit code 2."""
    try:
        main(None)
    except UserError as exc:
        sys.stderr.write(f"error: {error_line(exc)}\n")
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130
    return 0
