"""LiveKit Agents (``livekit-agents`` 1.8) into a ``LiveSession``.

- ``attach(agent_session, live)``, after ``await agent_session.start(...)`` (RoomIO makes its
  input and output inside ``start``): wraps ``agent_session.input.audio`` (the user's audio, fed
  as it arrives) and, in follower mode, ``agent_session.output.audio`` in the style of LiveKit's
  own ``RecorderIO`` (``capture_frame`` feeds the voice as generated, ``flush`` ends a segment,
  ``clear_buffer`` is the interruption, ``pause``/``resume`` a possible false interruption, and
  the sink's ``playback_started``/``playback_progressed`` reports are the played-time anchors);
  and turns the session's ``agent_state_changed``, ``user_state_changed``,
  ``user_input_transcribed``, ``tool_execution_updated`` and ``agent_false_interruption`` into
  conversation events.
- ``ConvodriveAudioOutput``: player mode, convodrive is the speaker. Set it as
  ``agent_session.output.audio`` **before** ``start`` (so RoomIO publishes no voice); it feeds
  the session, paces ``capture_frame`` to the voice queued ahead of the speaker (as RoomIO's
  ``rtc.AudioSource`` does), and tells LiveKit when each segment started and finished playing
  from the session's thread through ``loop.call_soon_threadsafe``.

LiveKit stamps wall time (``time.time()``); every time here is converted to ``time.monotonic()``.
"""

from __future__ import annotations

import asyncio
import collections
import time
from typing import Any

from livekit import rtc
from livekit.agents import AgentSession
from livekit.agents.voice import io
from livekit.agents.voice.events import (
    AgentFalseInterruptionEvent,
    AgentStateChangedEvent,
    ToolExecutionUpdatedEvent,
    UserInputTranscribedEvent,
    UserStateChangedEvent,
)

from convodrive.agents.wall import to_mono, to_wall
from convodrive.generators.base import Event
from convodrive.pipeline.session import LiveSession, PlaybackReport


class PartnerInput(io.AudioInput):
    """The user's audio on its way to the agent, fed to the session stamped on arrival."""

    def __init__(self, live: LiveSession, source: io.AudioInput) -> None:
        super().__init__(label="convodrive", source=source)
        self.live = live

    async def __anext__(self) -> rtc.AudioFrame:
        assert self.source is not None
        frame = await self.source.__anext__()
        at = time.monotonic() - frame.duration  # frames carry no capture time: arrival is the clock
        self.live.feed_partner(frame.data, frame.sample_rate, frame.num_channels, at=at)
        return frame


class FollowedOutput(io.AudioOutput):
    """Follower mode: a wrapper above the framework's sink that feeds the session the voice as
    generated and the sink's play reports. A segment runs from its first ``capture_frame`` to
    ``flush`` or ``clear_buffer``; reports concern the oldest segment not yet finished."""

    def __init__(self, live: LiveSession, sink: io.AudioOutput) -> None:
        super().__init__(label="convodrive", capabilities=io.AudioOutputCapabilities(pause=True), next_in_chain=sink)
        self.live = live
        self._count = 0
        self._capturing: int | None = None
        self._playing: collections.deque[int] = collections.deque()
        """Segments captured and not yet reported finished, oldest first."""
        self._held = False
        self._cut = True
        """Cleared since the last capture (LiveKit clears twice on an interruption)."""

    @property
    def sample_rate(self) -> int | None:
        return self.next_in_chain.sample_rate if self.next_in_chain else None

    async def capture_frame(self, frame: rtc.AudioFrame) -> None:
        if self._capturing is None:
            self._count += 1
            self._capturing = self._count
            self._playing.append(self._count)
        self._cut = False
        self.live.feed_self(frame.data, frame.sample_rate, self._capturing, frame.num_channels)
        await super().capture_frame(frame)
        if self.next_in_chain:
            await self.next_in_chain.capture_frame(frame)

    def flush(self) -> None:
        super().flush()
        if self._capturing is not None:
            self.live.end_self(self._capturing)
            self._capturing = None
        if self.next_in_chain:
            self.next_in_chain.flush()

    def clear_buffer(self) -> None:
        if not self._cut:
            self.live.clear_self()
        self._capturing, self._cut, self._held = None, True, False
        if self.next_in_chain:
            self.next_in_chain.clear_buffer()

    def pause(self) -> None:
        if not self._held:
            self.live.pause_self()
        self._held = True
        super().pause()

    def resume(self) -> None:
        if self._held:  # LiveKit also resumes before each reply
            self.live.resume_self()
        self._held = False
        super().resume()

    def on_playback_started(self, *, created_at: float) -> None:
        if self._playing:
            self.live.self_played(self._playing[0], 0.0, at=to_mono(created_at))
        super().on_playback_started(created_at=created_at)

    def on_playback_progressed(self, *, started_at: float, offset: float, duration: float) -> None:
        if self._playing:
            self.live.self_played(self._playing[0], offset, at=to_mono(started_at))
        super().on_playback_progressed(started_at=started_at, offset=offset, duration=duration)

    def on_playback_finished(
        self, *, playback_position: float, interrupted: bool, synchronized_transcript: str | None = None
    ) -> None:
        if self._playing:
            self._playing.popleft()
        super().on_playback_finished(
            playback_position=playback_position,
            interrupted=interrupted,
            synchronized_transcript=synchronized_transcript,
        )


class ConvodriveAudioOutput(io.AudioOutput):
    """Player mode's speaker: ``agent_session.output.audio = ConvodriveAudioOutput(live)`` before
    ``start``. It must be built on the session's event loop (it keeps it for the reports)."""

    def __init__(self, live: LiveSession, loop: asyncio.AbstractEventLoop | None = None) -> None:
        if not live.player:
            raise ValueError("ConvodriveAudioOutput plays the voice: open the session in player mode")
        super().__init__(label="convodrive", capabilities=io.AudioOutputCapabilities(pause=True))
        self.live = live
        self.loop = loop or asyncio.get_running_loop()
        self._count = 0
        self._capturing: int | None = None
        self._pending: dict[int, float] = {}
        """Segments captured and not yet reported finished, with when each started playing."""
        self._held = False
        self._cut = True
        live.on_playback(self._from_player)

    async def capture_frame(self, frame: rtc.AudioFrame) -> None:
        if self._capturing is None:
            self._count += 1
            self._capturing = self._count
            self._pending[self._count] = 0.0
        self._cut = False
        await super().capture_frame(frame)
        self.live.feed_self(frame.data, frame.sample_rate, self._capturing, frame.num_channels)
        while self.live.self_backlog() > self.live.write_ahead and self._capturing is not None:
            await asyncio.sleep(0.005)

    def flush(self) -> None:
        super().flush()
        if self._capturing is not None:
            self.live.end_self(self._capturing)
            self._capturing = None

    def clear_buffer(self) -> None:
        self._capturing, self._held = None, False
        if self._cut:  # LiveKit clears twice on an interruption
            return
        self._cut = True
        cut = list(self._pending)
        self.live.clear_self()  # the player reports the playing segments finished (interrupted)
        self.loop.call_soon(self._finish_unplayed, cut)  # after those reports: the rest never played

    def pause(self) -> None:
        if not self._held:
            self.live.pause_self()
        self._held = True

    def resume(self) -> None:
        if self._held:  # LiveKit also resumes before each reply
            self.live.resume_self()
        self._held = False

    def _from_player(self, report: PlaybackReport) -> None:
        """The session's thread: hand the report to LiveKit's loop."""
        try:
            self.loop.call_soon_threadsafe(self._deliver, report)
        except RuntimeError:  # the loop is closed: nobody listens any more
            pass

    def _deliver(self, report: PlaybackReport) -> None:
        if report.segment not in self._pending:
            return
        if report.kind == "started":
            self._pending[report.segment] = to_wall(report.at)
            self.on_playback_started(created_at=self._pending[report.segment])
            return
        started = self._pending.pop(report.segment) or to_wall(report.at) - report.position
        if report.position > 0:
            self.on_playback_progressed(started_at=started, offset=0.0, duration=report.position)
        self.on_playback_finished(playback_position=report.position, interrupted=report.interrupted)

    def _finish_unplayed(self, cut: list[int]) -> None:
        for segment in cut:
            if self._pending.pop(segment, None) is not None:
                self.on_playback_finished(playback_position=0.0, interrupted=True)


def attach(agent_session: AgentSession, live: LiveSession) -> None:
    """Tie ``live`` to a started ``agent_session`` (see the module docstring)."""
    if agent_session.input.audio is not None:
        agent_session.input.audio = PartnerInput(live, agent_session.input.audio)
    sink = agent_session.output.audio
    if not live.player:
        if sink is None:
            raise ValueError("follower mode follows the session's audio output, and it has none")
        agent_session.output.audio = FollowedOutput(live, sink)
    elif not _in_chain(sink, ConvodriveAudioOutput):
        raise ValueError("player mode: set agent_session.output.audio = ConvodriveAudioOutput(live) before start")
    _subscribe(agent_session, live)


def _in_chain(sink: io.AudioOutput | None, kind: type) -> bool:
    while sink is not None:
        if isinstance(sink, kind):
            return True
        sink = sink.next_in_chain
    return False


def _subscribe(agent_session: AgentSession, live: LiveSession) -> None:
    def agent_state(ev: AgentStateChangedEvent) -> None:
        at = to_mono(ev.created_at)
        if ev.old_state == "thinking":
            live.event(Event.THINKING_END, at)
        if ev.new_state == "thinking":
            live.event(Event.THINKING_START, at)
        elif ev.new_state == "idle":
            live.event(Event.IDLE, at)
        if not live.player and ev.old_state == "speaking":  # the player knows its own end
            live.event(Event.SPEAKING_END, at)

    def user_state(ev: UserStateChangedEvent) -> None:
        at = to_mono(ev.created_at)
        if ev.old_state == "away":
            live.event(Event.USER_BACK, at)
        if ev.new_state == "speaking":
            live.event(Event.USER_SPEECH_START, at)
        elif ev.old_state == "speaking":
            live.event(Event.USER_SPEECH_STOP, at)
        if ev.new_state == "away":
            live.event(Event.USER_AWAY, at)

    def transcribed(ev: UserInputTranscribedEvent) -> None:
        if ev.is_final:
            live.event(Event.USER_TURN_END, to_mono(ev.created_at))

    def tool(ev: ToolExecutionUpdatedEvent) -> None:
        kind = {"tool_call_started": Event.TOOL_START, "tool_call_ended": Event.TOOL_END}.get(ev.update.type)
        if kind is not None:
            live.event(kind, to_mono(ev.created_at), tool=getattr(ev.update, "call_id", None))

    def false_interruption(ev: AgentFalseInterruptionEvent) -> None:
        if ev.resumed:
            live.event(Event.RESUMED, to_mono(ev.created_at))

    handlers: dict[Any, Any] = {
        "agent_state_changed": agent_state,
        "user_state_changed": user_state,
        "user_input_transcribed": transcribed,
        "tool_execution_updated": tool,
        "agent_false_interruption": false_interruption,
    }
    for name, handler in handlers.items():
        agent_session.on(name, handler)
