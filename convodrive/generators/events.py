"""Conversation events: what a voice agent knows about the conversation and the audio cannot tell.

A live session (``convodrive.pipeline.session``) hands each event to its generator
(``Generator.on_event``) stamped with a time on the run's time line (seconds, the frames' own
``time``). The set is closed, so every generator, learned or a plugin, can rely on it; a
generator that ignores events moves as it would from the audio alone.

Events may arrive after the frames they concern were made (a framework that tells late), or
ahead of them (the session knows when queued speech will start playing): ``EventLog`` keeps them
in time order, and ``state_at(t)`` is the conversation's state at frame time ``t`` from every
event stamped at or before ``t`` that has arrived so far. Offline runs have no events, so
``generate`` stays equal to ``stream``.
"""

from __future__ import annotations

import bisect
import dataclasses
import enum
import threading
from collections.abc import Mapping
from typing import Any


class Event(enum.Enum):
    """The closed set of conversation events (issue 33's table)."""

    USER_SPEECH_START = "user_speech_start"
    """Voice activity of the user began (raw VAD)."""
    USER_SPEECH_STOP = "user_speech_stop"
    USER_TURN_START = "user_turn_start"
    """The framework decided the user has the turn."""
    USER_TURN_END = "user_turn_end"
    """The user's turn ended: the agent thinks from here until its first played sample."""
    THINKING_START = "thinking_start"
    THINKING_END = "thinking_end"
    TOOL_START = "tool_start"
    """A tool call is in progress."""
    TOOL_END = "tool_end"
    SPEAKING_START = "speaking_start"
    """The agent's first sample of a reply is played."""
    SPEAKING_END = "speaking_end"
    INTERRUPTED = "interrupted"
    """The agent's voice was cut: nothing queued after this will be played."""
    PAUSED = "paused"
    RESUMED = "resumed"
    USER_AWAY = "user_away"
    USER_BACK = "user_back"
    IDLE = "idle"
    """Nobody speaks and the agent waits (ended by any other event but USER_AWAY)."""


@dataclasses.dataclass(frozen=True)
class ConversationEvent:
    kind: Event
    at: float
    """Seconds on the run's time line (frame k is at k / 30)."""
    info: Mapping[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class AgentState:
    """The conversation at one instant; each ``*_since`` is the time the condition began, None
    when it does not hold."""

    thinking_since: float | None = None
    tool_since: float | None = None
    speaking_since: float | None = None
    interrupted_since: float | None = None
    paused_since: float | None = None
    user_speaking_since: float | None = None
    user_away_since: float | None = None
    idle_since: float | None = None

    @property
    def planning(self) -> bool:
        """Thinking or running a tool, and not speaking: a person would look away and be silent."""
        return (self.thinking_since is not None or self.tool_since is not None) and self.speaking_since is None

    @property
    def mouth_shut(self) -> bool:
        """Nothing the agent says now will be heard: cut, paused, or still planning what to say."""
        return self.interrupted_since is not None or self.paused_since is not None or self.planning

    def idle_for(self, t: float) -> float:
        """Seconds the conversation has been idle at time ``t`` (0 when it is not)."""
        return 0.0 if self.idle_since is None else max(t - self.idle_since, 0.0)


def apply(state: AgentState, event: ConversationEvent) -> AgentState:
    """The state after ``event``: one rule per event, so every generator reads them the same way."""
    k, t = event.kind, event.at
    r = dataclasses.replace
    if k is not Event.IDLE and k is not Event.USER_AWAY and state.idle_since is not None:
        state = r(state, idle_since=None)
    if k is Event.USER_SPEECH_START or k is Event.USER_TURN_START:
        return r(state, user_speaking_since=state.user_speaking_since or t, user_away_since=None)
    if k is Event.USER_SPEECH_STOP:
        return r(state, user_speaking_since=None)
    if k is Event.USER_TURN_END:
        return r(state, user_speaking_since=None, thinking_since=state.thinking_since or t)
    if k is Event.THINKING_START:
        return r(state, thinking_since=state.thinking_since or t)
    if k is Event.THINKING_END:
        return r(state, thinking_since=None)
    if k is Event.TOOL_START:
        return r(state, tool_since=state.tool_since or t)
    if k is Event.TOOL_END:
        return r(state, tool_since=None)
    if k is Event.SPEAKING_START:
        return r(state, speaking_since=t, thinking_since=None, interrupted_since=None, paused_since=None)
    if k is Event.SPEAKING_END:
        return r(state, speaking_since=None)
    if k is Event.INTERRUPTED:
        return r(state, interrupted_since=t, speaking_since=None, paused_since=None)
    if k is Event.PAUSED:
        return r(state, paused_since=state.paused_since or t)
    if k is Event.RESUMED:
        return r(state, paused_since=None)
    if k is Event.USER_AWAY:
        return r(state, user_away_since=state.user_away_since or t, user_speaking_since=None)
    if k is Event.USER_BACK:
        return r(state, user_away_since=None)
    if k is Event.IDLE:
        return AgentState(idle_since=state.idle_since or t, user_away_since=state.user_away_since)
    raise ValueError(f"unknown conversation event {k!r}")


class EventLog:
    """Events in time order, written from any thread, read by the generator's.

    Events older than ``keep`` before the latest one are folded into a base state, so a long run
    replays a bounded list per query."""

    def __init__(self, keep: int = 256) -> None:
        self._lock = threading.Lock()
        self._events: list[tuple[float, int, ConversationEvent]] = []
        self._base = AgentState()
        self._count = 0
        self.keep = keep

    def add(self, event: ConversationEvent) -> None:
        with self._lock:
            self._count += 1
            bisect.insort(self._events, (event.at, self._count, event))
            while len(self._events) > self.keep:
                self._base = apply(self._base, self._events.pop(0)[2])

    def __len__(self) -> int:
        with self._lock:
            return len(self._events)

    def state_at(self, t: float) -> AgentState:
        with self._lock:
            events = list(self._events)
            state = self._base
        for at, _, event in events:
            if at > t:
                break
            state = apply(state, event)
        return state

    def states(self, times: list[float]) -> list[AgentState]:
        """``state_at`` for ascending ``times``, in one pass over the events."""
        with self._lock:
            events = list(self._events)
            state = self._base
        out, i = [], 0
        for t in times:
            while i < len(events) and events[i][0] <= t:
                state = apply(state, events[i][2])
                i += 1
            out.append(state)
        return out
