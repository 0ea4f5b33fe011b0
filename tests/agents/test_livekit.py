"""LiveKit's real ``AgentSession`` driving a live session, as LiveKit's own tests run it: no room
(so no server), a stub LLM, an agent whose ``llm_node`` thinks a while and answers with a line and
whose ``tts_node`` yields 20 ms frames of espeak-ng speech, a paced microphone, and in follower mode
a fake speaker that sleeps each frame's duration and reports as RoomIO's sink does (started at its
first frame, progressed and finished at the segment's end or clear). ``record=False`` and no job
context: nothing is recorded or uploaded. The recorder is the backend."""

from __future__ import annotations

from tests.conftest import require

pytestmark = [require("livekit"), require("espeak")]

import asyncio  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from livekit import rtc  # noqa: E402
from livekit.agents import Agent, AgentSession, llm  # noqa: E402
from livekit.agents.voice import io  # noqa: E402
from livekit.agents.voice.events import UserInputTranscribedEvent, UserStateChangedEvent  # noqa: E402

from convodrive.agents.livekit import ConvodriveAudioOutput, attach  # noqa: E402
from convodrive.agents.wall import to_mono, to_wall  # noqa: E402
from convodrive.audio.source import ANALYSIS_RATE  # noqa: E402
from convodrive.generators.base import Event  # noqa: E402
from convodrive.pipeline.session import LiveSession  # noqa: E402
from tests.pipeline.session.helpers import CLOSED, eye_angle, kinds, mouth, told_at, voice  # noqa: E402

RATE = ANALYSIS_RATE
FRAME = 0.02
THINK = 1.0


class StubLLM(llm.LLM):
    """LiveKit wants an LLM before it generates a reply, even with ``llm_node`` overridden."""

    def chat(self, **kwargs):  # type: ignore[override]
        raise NotImplementedError


class Mic(io.AudioInput):
    """20 ms of silence every 20 ms."""

    def __init__(self) -> None:
        super().__init__(label="mic")

    async def __anext__(self) -> rtc.AudioFrame:
        await asyncio.sleep(FRAME)
        n = int(FRAME * RATE)
        return rtc.AudioFrame(bytes(2 * n), RATE, 1, n)


class FakeSpeaker(io.AudioOutput):
    """RoomIO's sink without the room: a queue of ``QUEUE`` seconds (RoomIO's ``rtc.AudioSource``
    holds 200 ms) before a speaker that plays at the rate of real time from a segment's first
    frame, however late the test's loop runs; reports as RoomIO's does (started at the first
    frame, progressed and finished once the segment has played or is cleared)."""

    QUEUE = 0.2

    def __init__(self) -> None:
        super().__init__(label="fake-speaker", capabilities=io.AudioOutputCapabilities(pause=True), sample_rate=RATE)
        self.starts: list[float] = []
        self._started: float | None = None
        """When (monotonic) the segment's first sample played; None between segments."""
        self._pushed = 0.0
        self._pending: asyncio.Handle | None = None

    async def capture_frame(self, frame: rtc.AudioFrame) -> None:
        await super().capture_frame(frame)
        if self._started is None:
            self._started = time.monotonic()
            self.starts.append(self._started)
            self.on_playback_started(created_at=to_wall(self._started))
        self._pushed += frame.duration
        queued = self._queued()
        if queued > self.QUEUE:  # the queue is full: wait as AudioSource.capture_frame does
            await asyncio.sleep(queued - self.QUEUE)

    def _queued(self) -> float:
        """Seconds of the segment taken and not yet played (0 between segments)."""
        return 0.0 if self._started is None else max(self._pushed - (time.monotonic() - self._started), 0.0)

    def _finish(self, interrupted: bool) -> None:
        started, played = self._started, self._pushed - self._queued()
        self._started, self._pushed = None, 0.0
        if started is not None:
            self.on_playback_progressed(started_at=to_wall(started), offset=0.0, duration=played)
            self.on_playback_finished(playback_position=played, interrupted=interrupted)

    def flush(self) -> None:
        super().flush()  # finished once what is queued has played, unless cleared before
        if self._started is not None:
            self._pending = asyncio.get_running_loop().call_later(self._queued(), self._finish, False)

    def clear_buffer(self) -> None:
        if self._pending is not None:
            self._pending.cancel()
        self._finish(True)


class Scripted(Agent):
    """Thinks ``THINK`` seconds, then says a line; the first reply is 2 s of speech."""

    def __init__(self) -> None:
        super().__init__(instructions="answer")
        self.replies = 0

    async def llm_node(self, chat_ctx, tools, model_settings):  # type: ignore[override]
        await asyncio.sleep(THINK)
        yield "The train leaves at nine."

    async def tts_node(self, text, model_settings):  # type: ignore[override]
        async for _ in text:
            pass
        self.replies += 1
        pcm = voice() if self.replies > 1 else voice()[: 2 * RATE]
        n = int(FRAME * RATE)
        for i in range(0, len(pcm) - n + 1, n):
            yield rtc.AudioFrame(pcm[i : i + n].tobytes(), RATE, 1, n)


async def converse(live: LiveSession, cut_after: float) -> tuple[AgentSession, io.AudioOutput, dict, list]:
    """A user turn, a reply played whole, a second reply interrupted ``cut_after`` seconds in;
    returns the session, its sink, when (monotonic) each step was sent, and the sink's reports."""
    session = AgentSession(vad=None, llm=StubLLM(), turn_handling={"turn_detection": "manual"})
    session.input.audio = Mic()
    sink: io.AudioOutput = ConvodriveAudioOutput(live) if live.player else FakeSpeaker()
    session.output.audio = sink
    await session.start(Scripted(), record=False)
    attach(session, live)
    reports: list = []
    sink.on("playback_started", lambda ev: reports.append(("started", time.monotonic(), ev)))
    sink.on("playback_finished", lambda ev: reports.append(("finished", time.monotonic(), ev)))
    marks: dict = {}
    while live.time_at(time.monotonic()) is None:  # the run starts with the partner's audio
        await asyncio.sleep(0.01)
    await asyncio.sleep(0.7)
    session.emit("user_state_changed", UserStateChangedEvent(old_state="listening", new_state="speaking"))
    await asyncio.sleep(0.8)
    session.emit("user_state_changed", UserStateChangedEvent(old_state="speaking", new_state="listening"))
    session.emit("user_input_transcribed", UserInputTranscribedEvent(transcript="when?", is_final=True))
    marks["turn_end"] = time.monotonic()
    await session.generate_reply(user_input="When does the train leave?")
    await asyncio.sleep(0.3)
    marks["reply2"] = time.monotonic()
    handle = session.generate_reply(user_input="And then?")
    while sum(r[0] == "started" for r in reports) < 2:
        await asyncio.sleep(0.005)
    await asyncio.sleep(cut_after)
    marks["cut"] = time.monotonic()
    session.interrupt()
    await asyncio.wait_for(handle.wait_for_playout(), 5)
    marks["interrupted"] = handle.interrupted
    await asyncio.sleep(0.8)
    await session.aclose()
    return session, sink, marks, reports


def run(tmp_path, mode: str):
    live = LiveSession.open(
        mode=mode, backends=("record",), out_dir=tmp_path, generator_options={"phones": False}, self_rate=RATE
    )
    try:
        _, sink, marks, reports = asyncio.run(converse(live, cut_after=1.0))
    finally:
        live.close()
    return live, sink, marks, reports


def check_thinking(tmp_path, live: LiveSession, speaking_at: float, shown: float) -> None:
    """From the first THINKING_START to ``speaking_at`` (time line): eyes away, mouth shut."""
    think_at = [e.at for _, e in live.events if e.kind is Event.THINKING_START][0]
    eyes = eye_angle(tmp_path)
    thinking = slice(int((think_at + 0.3) * 30), int((speaking_at - 0.05) * 30))
    before = slice(int((think_at - 0.6) * 30), int((think_at - 0.1) * 30))
    assert eyes[thinking].mean() > eyes[before].mean() + 8.0
    times, jaw = mouth(live)
    assert jaw[(times > shown + 0.1) & (times < shown + THINK - 0.1)].max() < CLOSED


@pytest.mark.timeout(120)
def test_follower_behind_livekits_audio_output(tmp_path):
    live, speaker, marks, reports = run(tmp_path, "follower")
    order = kinds(live)
    assert order[:4] == [Event.USER_SPEECH_START, Event.USER_SPEECH_STOP, Event.USER_TURN_END, Event.THINKING_START]
    assert order.index(Event.SPEAKING_START) > order.index(Event.THINKING_START)
    assert order.index(Event.INTERRUPTED) > order.index(Event.SPEAKING_START)
    assert marks["interrupted"] and [r[2].interrupted for r in reports if r[0] == "finished"] == [False, True]
    # Played-time anchors: each reply starts on the time line within one frame of the fake speaker.
    starts = [e.at for _, e in live.events if e.kind is Event.SPEAKING_START and "segment" in e.info]
    assert len(starts) == 2 and len(speaker.starts) == 2
    for at, played in zip(starts, speaker.starts, strict=True):
        assert abs(at - (live.time_at(played) + live.delay)) < FRAME + 0.005
    # The interruption: the mouth moves before it and is shut 100 ms after it shows (delay late).
    times, jaw = mouth(live)
    shown = marks["cut"] + live.delay
    assert jaw[(times > shown - 0.8) & (times < shown - 0.05)].max() > 0.2
    assert jaw[times > shown + 0.1].max() < CLOSED
    check_thinking(tmp_path, live, starts[0], marks["turn_end"] + live.delay)


@pytest.mark.timeout(120)
def test_player_plays_through_convodrive_audio_output(tmp_path):
    live, _, marks, reports = run(tmp_path, "player")
    order = kinds(live)
    assert order[:4] == [Event.USER_SPEECH_START, Event.USER_SPEECH_STOP, Event.USER_TURN_END, Event.THINKING_START]
    assert order.index(Event.SPEAKING_START) > order.index(Event.THINKING_START)
    assert Event.INTERRUPTED in order[order.index(Event.SPEAKING_START) :]
    finished = [r[2] for r in reports if r[0] == "finished"]
    assert marks["interrupted"] and [f.interrupted for f in finished] == [False, True]
    # The whole first reply played: its own 2 s, silence a starved writer left between its
    # frames not counted.
    assert abs(finished[0].playback_position - 2.0) < 0.03
    played = live.speaker.samples()
    # LiveKit's playback_started is stamped with when the speaker played the reply's first sample
    # (the ring holds exact zeros before it), however late the session's thread noticed it.
    first_played = live.speaker.mono_of(np.flatnonzero(played)[0] / RATE)
    started = [r for r in reports if r[0] == "started"]
    assert abs(to_mono(started[0][2].created_at) - first_played) < 0.01
    told = told_at(live, Event.INTERRUPTED)  # the output's clear_buffer, after LiveKit's tasks
    cut = int((live.speaker.position_at(told) + 0.03) * RATE)
    assert np.abs(played[cut:]).max() < 1e-6  # nothing of the cut reply plays after the cut
    times, jaw = mouth(live)
    assert jaw[(times > marks["cut"] - 0.8) & (times < marks["cut"])].max() > 0.2
    assert jaw[times > told + 0.1].max() < CLOSED
    speaking = [e.at for _, e in live.events if e.kind is Event.SPEAKING_START][0]
    check_thinking(tmp_path, live, speaking, marks["turn_end"])
