"""Pipecat (``pipecat-ai`` 1.14) into a ``LiveSession``.

- ``ConvodriveObserver``: an observer (Pipecat gives each its own queue and task, so it cannot
  stall the pipeline). It feeds the user's audio as it arrives, turns state frames into
  conversation events, and in follower mode feeds the TTS audio as generated and reports each
  chunk the output transport pushes on after writing it as played (``self_played``). Pipecat's
  bot speaking frames are its speaking events, but for the start it announces for the chunk its
  transport was writing when an interruption came (that chunk belongs to the cleared reply).
- ``ConvodriveOutputTransport``: player mode, convodrive is the speaker. Its ``write_audio_frame``
  feeds the session and returns once the voice queued ahead of the speaker is under the
  session's lead, so the writes go at the pace of playing and Pipecat's own speaking events stay
  true; an ``InterruptionFrame`` clears the voice at once.

A push is stamped when it happened, not when the observer's task got to it (on a loaded machine
that comes tens of milliseconds later): ``FramePushed.timestamp`` counts from the worker's clock's
start on the monotonic clock, and that start is the least ``arrival - timestamp`` seen so far (a
queue only adds lag). VAD frames carry wall time, converted with the offset measured here.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from pipecat.frames.frames import (
    BotStartedSpeakingFrame,
    BotStoppedSpeakingFrame,
    FunctionCallCancelFrame,
    FunctionCallInProgressFrame,
    FunctionCallResultFrame,
    FunctionCallsStartedFrame,
    InputAudioRawFrame,
    InterruptionFrame,
    LLMFullResponseStartFrame,
    OutputAudioRawFrame,
    StartFrame,
    TTSAudioRawFrame,
    TTSStartedFrame,
    TTSStoppedFrame,
    UserStartedSpeakingFrame,
    UserStoppedSpeakingFrame,
    VADUserStartedSpeakingFrame,
    VADUserStoppedSpeakingFrame,
)
from pipecat.observers.base_observer import BaseObserver, FramePushed
from pipecat.processors.frame_processor import FrameDirection
from pipecat.transports.base_output import BaseOutputTransport
from pipecat.transports.base_transport import TransportParams

from convodrive.agents.wall import to_mono
from convodrive.generators.base import Event
from convodrive.pipeline.session import LiveSession

STATE_EVENTS: dict[type, Event] = {
    UserStartedSpeakingFrame: Event.USER_TURN_START,
    UserStoppedSpeakingFrame: Event.USER_TURN_END,
    LLMFullResponseStartFrame: Event.THINKING_START,
    FunctionCallsStartedFrame: Event.TOOL_START,
    FunctionCallInProgressFrame: Event.TOOL_START,
    FunctionCallResultFrame: Event.TOOL_END,
    FunctionCallCancelFrame: Event.TOOL_END,
}
"""Frames whose first push is an event in both modes."""
FOLLOWER_EVENTS: dict[type, Event] = {
    BotStartedSpeakingFrame: Event.SPEAKING_START,
    BotStoppedSpeakingFrame: Event.SPEAKING_END,
}
"""In player mode the session knows these better (when the speaker plays the samples)."""


class ConvodriveObserver(BaseObserver):
    """Feeds ``session`` from every push in the pipeline; pass it as ``PipelineWorker(...,
    observers=[ConvodriveObserver(session)])``."""

    def __init__(self, session: LiveSession, **kwargs: Any) -> None:
        super().__init__(observe_every_push=True, **kwargs)
        self.session = session
        self._segment: Any = 0
        self._played: dict[Any, float] = {}
        """Seconds of each segment reported played (follower mode)."""
        self._clock_start = float("inf")
        """The worker clock's start on the monotonic clock, as far as the arrivals tell."""
        self._voiced = False
        """Follower mode: TTS audio came since the last interruption."""
        self._bot_speaking = False
        """Follower mode: the last bot speaking event posted was a start."""

    def _pushed_at(self, data: FramePushed) -> float:
        """When (monotonic) the frame was pushed; its arrival if its processor had no clock yet."""
        arrival = time.monotonic()
        if data.timestamp <= 0:
            return arrival
        pushed = data.timestamp / 1e9
        self._clock_start = min(self._clock_start, arrival - pushed)
        return self._clock_start + pushed

    async def on_push_frame(self, data: FramePushed) -> None:
        frame, now = data.frame, self._pushed_at(data)
        session = self.session
        if isinstance(frame, InputAudioRawFrame):
            if data.first_push:
                session.feed_partner(frame.audio, frame.sample_rate, frame.num_channels, at=now - _seconds(frame))
            return
        if isinstance(frame, OutputAudioRawFrame):
            if not session.player:
                self._self_audio(data, frame, now)
            return
        if not data.first_push:
            return
        if isinstance(frame, TTSStartedFrame):
            self._segment = frame.context_id or self._segment
        elif isinstance(frame, TTSStoppedFrame) and not session.player:
            session.end_self(frame.context_id or self._segment)
        elif isinstance(frame, InterruptionFrame) and not session.player:
            self._voiced = False
            session.clear_self(now)  # player mode: the output transport clears
        elif isinstance(frame, VADUserStartedSpeakingFrame):
            session.event(Event.USER_SPEECH_START, to_mono(frame.timestamp - frame.start_secs))
        elif isinstance(frame, VADUserStoppedSpeakingFrame):
            session.event(Event.USER_SPEECH_STOP, to_mono(frame.timestamp - frame.stop_secs))
        elif data.direction == FrameDirection.DOWNSTREAM:  # broadcast frames: one copy
            kind = STATE_EVENTS.get(type(frame))
            if kind is None and not session.player:
                kind = self._bot_speaking_event(type(frame))
            if kind is not None:
                session.event(kind, now, frame=type(frame).__name__)

    def _bot_speaking_event(self, frame_type: type) -> Event | None:
        """Pipecat's bot speaking frames as events, but for the chunk its output transport was
        already writing when an interruption came: it still plays that chunk (of a cleared
        segment) and says the bot started again, with no stop until a fallback seconds later."""
        kind = FOLLOWER_EVENTS.get(frame_type)
        if kind is Event.SPEAKING_START and (self._bot_speaking or not self._voiced):
            return None
        if kind is Event.SPEAKING_END and not self._bot_speaking:
            return None
        if kind is not None:
            self._bot_speaking = kind is Event.SPEAKING_START
        return kind

    def _self_audio(self, data: FramePushed, frame: OutputAudioRawFrame, now: float) -> None:
        segment = getattr(frame, "context_id", None) or self._segment
        if isinstance(data.source, BaseOutputTransport):  # written: played (chunks made there)
            if data.direction == FrameDirection.DOWNSTREAM:
                offset = self._played.get(segment, 0.0)
                self.session.self_played(segment, offset, at=now - _seconds(frame))
                self._played[segment] = offset + _seconds(frame)
        elif data.first_push and isinstance(frame, TTSAudioRawFrame):
            self._voiced = True
            self.session.feed_self(frame.audio, frame.sample_rate, segment, frame.num_channels)


def _seconds(frame: Any) -> float:
    return frame.num_frames / frame.sample_rate if frame.sample_rate else 0.0


class ConvodriveOutputTransport(BaseOutputTransport):
    """Player mode's speaker: the last processor of the pipeline (``Pipeline([..., tts, this])``)."""

    def __init__(self, session: LiveSession, params: TransportParams | None = None, **kwargs: Any) -> None:
        if not session.player:
            raise ValueError("ConvodriveOutputTransport plays the voice: open the session in player mode")
        params = params or TransportParams(
            audio_out_enabled=True, audio_out_sample_rate=session.request.self_rate, audio_out_end_silence_secs=0
        )
        super().__init__(params, **kwargs)
        self.session = session
        self._segment: Any = 0

    async def start(self, frame: StartFrame) -> None:
        await super().start(frame)
        await self.set_transport_ready(frame)

    async def write_audio_frame(self, frame: OutputAudioRawFrame) -> bool:
        self.session.feed_self(frame.audio, frame.sample_rate, self._segment, frame.num_channels)
        while self.session.self_backlog() > self.session.write_ahead:
            await asyncio.sleep(0.005)
        return True

    async def process_frame(self, frame: Any, direction: FrameDirection) -> None:
        if isinstance(frame, InterruptionFrame):
            self.session.clear_self()
        elif isinstance(frame, TTSStartedFrame):
            self._segment = frame.context_id or object()
        await super().process_frame(frame, direction)
        if isinstance(frame, TTSStoppedFrame):
            self.session.end_self(self._segment)
