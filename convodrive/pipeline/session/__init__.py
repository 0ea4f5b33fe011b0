"""Live sessions a voice agent drives (Pipecat, LiveKit, your own loop): ``LiveSession``.

- ``session``: the session (player and follower modes, every call non-blocking);
- ``inputs``: the audio the agent pushes (partner, its own voice by segment);
- ``follower``: placing a voice the framework plays by its play reports;
- ``playing``: player mode's playback reports back to the framework;
- ``speaker``: a speaker with no sound card (tests, benchmarks, voices sent elsewhere).
"""

from convodrive.generators.events import ConversationEvent, Event
from convodrive.pipeline.session.playing import PlaybackReport
from convodrive.pipeline.session.session import LiveSession, SessionRequest

__all__ = ["ConversationEvent", "Event", "LiveSession", "PlaybackReport", "SessionRequest"]
