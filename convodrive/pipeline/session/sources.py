"""Where a live session's audio comes from and goes, and the margins that place it in time.

The agent's voice is fed by the framework (``feed_self``) or read from a source (a file, raw PCM
on stdin, a socket a speech synthesiser writes into; ``audio.live.self_voice``); the partner is
fed (``feed_partner``), a microphone, or a file played as one (``audio.live.capture``); the voice
plays on an output device or a ``virtual`` speaker; a monitor may record what the speaker played.
Everything opens before any backend, so a mistake costs nothing; each ``UserError`` names the
request's field as the caller calls it (``convodrive live``: its options).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from convodrive.audio.live import capture
from convodrive.audio.live.capture import FileAsMicrophone, MicrophoneInput, NoPartner, PartnerInput, Recording
from convodrive.audio.live.devices import find_device
from convodrive.audio.live.feeder import SelfVoiceFeeder
from convodrive.audio.live.playback import Playback
from convodrive.audio.live.self_voice import TcpVoice, VoiceSource, open_voice
from convodrive.audio.source import SUPPORTED_EXTENSIONS
from convodrive.pipeline.session.inputs import PushedPartner
from convodrive.pipeline.session.speaker import VirtualSpeaker
from convodrive.plumbing.errors import InputFileError

SELF_MARGIN = 0.015
"""Self voice queued this much beyond the look-ahead: the feeder's poll, resampling, generation."""
SELF_JITTER = 0.04
"""Room for a streamed voice to arrive unevenly before the feeder would pad it with silence."""
PARTNER_GRACE = capture.BLOCK_SECONDS + 0.005
"""A partner sample may arrive this long after capture (its block's length plus delivery)."""
GENERATION_MARGIN = 0.008
"""Time to make a frame once its audio is in: the assembler's poll (2 ms) and one generator step
(procedural's costs some two thousand small Python calls: 2-4 ms on a shared 2-core machine).
At 2 ms, a tenth of the frames of a live run there went out late."""
RING_SPARE = 1.0
"""Ring room beyond what the look-ahead needs, in seconds: what a CPU too busy to run us for a
while (a second) costs in neither underruns nor overruns."""

Speaker = Playback | VirtualSpeaker


def open_voice_source(spec: str, rate: int, name: str) -> VoiceSource:
    """The voice ``spec`` names (``open_voice``); a socket that asks for a token says so on stderr."""
    voice = open_voice(spec, rate)
    if isinstance(voice, TcpVoice) and voice.token is not None:
        sys.stderr.write(
            f"convodrive: {name} {voice.describe}: a speaker must first send the line {voice.token}, then its PCM\n"
        )
        sys.stderr.flush()
    return voice


def open_partner(spec: str | None, name: str, ready: Callable[[], bool], ring_seconds: float) -> PartnerInput:
    """None: fed by the framework; ``none``; an audio file (played from when ``ready()``); else a
    capture device whose ring holds ``ring_seconds``."""
    if spec is None:
        return PushedPartner()
    if spec == "none":
        return NoPartner()
    path = Path(spec)
    if path.is_file() or path.suffix.lower() in SUPPORTED_EXTENSIONS or "/" in spec:
        if not path.exists():
            raise InputFileError(path, f"no such file ({name} takes an audio file or a capture device)")
        return FileAsMicrophone(path, ready=ready)
    device = find_device(spec, "input", name)
    return MicrophoneInput(device, ring_seconds=ring_seconds, latency=capture.PARTNER_LATENCY_SECONDS)


def open_speaker(
    spec: str, rate: int, ring_seconds: float, play_latency: float | str, output_latency: float, name: str
) -> Speaker:
    """``virtual`` (no sound card, ``output_latency`` late), or an output device."""
    if spec == "virtual":
        return VirtualSpeaker(rate, ring_seconds, latency=output_latency)
    return Playback(find_device(spec, "output", name), rate, ring_seconds, play_latency)


def open_monitor(spec: str, name: str) -> Recording:
    """A capture device that hears the speaker, kept whole with its timing."""
    device = find_device(spec, "input", name)
    return Recording(MicrophoneInput(device, ring_seconds=2.0, keep_timing=True))


class DrainingPlayback:
    """What the clock holds: the speaker, which on close first lets the end of a finished voice
    leave it (at most ``DRAIN_SECONDS``), so the last word is heard."""

    DRAIN_SECONDS = 1.0

    def __init__(self, speaker: Speaker, feeder: Callable[[], SelfVoiceFeeder | None]) -> None:
        self.speaker = speaker
        self._feeder = feeder

    def start(self) -> None:
        self.speaker.start()

    def position_at(self, mono: float) -> float | None:
        return self.speaker.position_at(mono)

    def close(self) -> None:
        feeder = self._feeder()
        if feeder is not None and feeder.ended_at is not None:
            self.speaker.drain(feeder.ended_at, self.DRAIN_SECONDS)
        self.speaker.close()
