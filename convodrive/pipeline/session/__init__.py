"""Live sessions a voice agent drives (Pipecat, LiveKit, your own loop), and ``convodrive live``
itself (a player session fed by the command line's sources): ``LiveSession``.

- ``session``: the session's calls (player and follower modes, every call non-blocking);
- ``running``: its run: audio and backends opened, the scheduler, the clock, closing;
- ``sources``: the voice and partner sources (fed, a file, stdin, a socket, a microphone), the
  speaker, the monitor, and the margins that place both voices in time;
- ``measures``: latencies and the audio–motion offset; ``report``: the run report's live section;
- ``inputs``: the audio the agent pushes (partner, its own voice by segment);
- ``follower``: placing a voice the framework plays by its play reports;
- ``playing``: player mode's playback reports back to the framework;
- ``speaker``: a speaker with no sound card (tests, benchmarks, voices sent elsewhere).
"""

from convodrive.generators.events import ConversationEvent, Event
from convodrive.pipeline.session.playing import PlaybackReport
from convodrive.pipeline.session.session import LiveSession, SessionRequest

__all__ = ["ConversationEvent", "Event", "LiveSession", "PlaybackReport", "SessionRequest"]
