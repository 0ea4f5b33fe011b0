"""The generator plugin contract (DESIGN, "Plugins").

A generator turns dyadic audio chunks into canonical motion frames at 30 fps, streaming, with a
declared look-ahead: frame k may depend on audio up to (k + lookahead_frames + 1) / 30 seconds, and
exactly on ``lookahead_seconds`` past its start (k / 30 s), which a live run waits for.
The same seed must give the same frames. ``stream`` keeps its state local to the call, so one
generator can run several streams (takes) side by side. A generator declares its options once, as
the dataclass named by its ``Options`` attribute (``convodrive.plugins.options``); the constructor
parses whatever it is given into that, so ``self.options`` is always typed and checked.
"""

from __future__ import annotations

import abc
import itertools
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any, ClassVar

from convodrive.audio.source import AudioChunk, DyadicAudio
from convodrive.generators.events import AgentState, ConversationEvent, Event, EventLog
from convodrive.motion.clip import MotionClip, MotionFrame
from convodrive.plugins.options import PluginOptions, coerce_options

__all__ = ["AgentState", "ConversationEvent", "Event", "Generator", "take_seed"]


class Generator(abc.ABC):
    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    Options: ClassVar[type[PluginOptions]] = PluginOptions
    """The dataclass of this generator's options (the base class: none)."""
    live_options: ClassVar[Mapping[str, Any]] = {}
    """Option values a live run uses unless the config or the command line sets them: what keeps
    the latency low when a person waits for the robot's response."""

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        self.options = coerce_options(self.Options, options, plugin=f"generator {self.name}")
        self.conversation = EventLog()
        """The conversation events a live session sent (``on_event``); empty offline."""

    def on_event(self, event: ConversationEvent) -> None:
        """A conversation event (``generators.events``), from any thread, possibly late or ahead
        of the frames it concerns. The default keeps it in ``conversation``, where ``stream`` may
        read the state at each frame's time; a generator that ignores it moves from audio alone."""
        self.conversation.add(event)

    @property
    def lookahead_frames(self) -> int:
        """How many frames of future audio a frame needs; the streaming latency."""
        return 0

    @property
    def lookahead_seconds(self) -> float:
        """Audio past frame k's start that frame k needs, at most ``(lookahead_frames + 1) / 30``:
        a live partner's latency. Generators that need less than whole frames say so here."""
        return (self.lookahead_frames + 1) / 30.0

    @abc.abstractmethod
    def stream(self, chunks: Iterable[AudioChunk], seed: int = 0) -> Iterator[MotionFrame]:
        """Yield frames 0, 1, 2, ... as the chunks that determine them arrive.

        Frame k has ``time == k / 30``. The stream yields one frame per 1/30 s of audio (see
        ``motion_frames_for``) and then ends.
        """

    def report(self) -> dict[str, Any]:
        """JSON-able notes for the run report, asked after the run: ``warnings`` (a list of lines)
        is shown to the user; anything else is kept in the report's ``generator`` section."""
        return {}

    def stream_takes(self, chunks: Iterable[AudioChunk], seeds: Sequence[int]) -> Iterator[tuple[MotionFrame, ...]]:
        """Several takes of one audio stream, frame by frame: one frame per seed at each step.

        The default runs one ``stream`` per seed over a ``tee`` of the chunks (which buffers only
        the takes' small lag). Generators whose audio analysis does not depend on the seed should
        override this to analyse once and synthesise each take from the shared features.
        """
        chunk_streams = itertools.tee(chunks, len(seeds))
        return zip(*(self.stream(c, seed=s) for c, s in zip(chunk_streams, seeds)))

    def generate(self, audio: DyadicAudio, seed: int = 0, num_samples: int = 1) -> list[MotionClip]:
        """Offline: ``num_samples`` takes of the whole audio, take i seeded with ``take_seed(seed, i)``."""
        clips = []
        for i in range(num_samples):
            frames = list(self.stream(audio.chunks(), seed=take_seed(seed, i)))
            clips.append(MotionClip.from_frames(frames, metadata={"generator": self.name, "seed": take_seed(seed, i)}))
        return clips


def take_seed(seed: int, take: int) -> int:
    """Seed of take ``take`` of a run seeded ``seed``: take 0 uses the run's seed itself."""
    return int(seed) + 7919 * int(take)
