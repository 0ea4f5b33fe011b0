"""Pipecat's real pipeline worker driving a live session: follower mode behind an output
transport paced as a speaker plays (a fake speaker), player mode through
``ConvodriveOutputTransport``; the recorder as the backend. No network: nothing here talks to
a service, and Pipecat sends no usage data."""

from __future__ import annotations

from tests.conftest import require

pytestmark = [require("pipecat"), require("espeak")]

import asyncio  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from pipecat.frames.frames import (  # noqa: E402
    EndFrame,
    FunctionCallInProgressFrame,
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
)
from pipecat.pipeline.pipeline import Pipeline  # noqa: E402
from pipecat.pipeline.worker import PipelineWorker  # noqa: E402
from pipecat.transports.base_output import BaseOutputTransport  # noqa: E402
from pipecat.transports.base_transport import TransportParams  # noqa: E402
from pipecat.workers.runner import WorkerRunner  # noqa: E402

from convodrive.agents.pipecat import ConvodriveObserver, ConvodriveOutputTransport  # noqa: E402
from convodrive.audio.source import ANALYSIS_RATE  # noqa: E402
from convodrive.generators.base import Event  # noqa: E402
from convodrive.pipeline.session import LiveSession  # noqa: E402
from tests.pipeline.session.helpers import CHUNK, CLOSED, eye_angle, kinds, mouth, told_at, voice  # noqa: E402

RATE = ANALYSIS_RATE


class FakeSpeaker(BaseOutputTransport):
    """An output transport whose write returns when the chunk has played, on a clock that keeps
    real time (as Pipecat's own transports pace their writes): a late write does not make the
    speaker play slower."""

    def __init__(self) -> None:
        super().__init__(
            TransportParams(audio_out_enabled=True, audio_out_sample_rate=RATE, audio_out_end_silence_secs=0)
        )
        self.writes: list[float] = []
        self._played_until = 0.0

    async def start(self, frame: StartFrame) -> None:
        await super().start(frame)
        await self.set_transport_ready(frame)

    async def write_audio_frame(self, frame: OutputAudioRawFrame) -> bool:
        now = time.monotonic()
        self.writes.append(now)
        self._played_until = max(self._played_until, now) + frame.num_frames / frame.sample_rate
        await asyncio.sleep(self._played_until - now)
        return True


def reply(pcm: np.ndarray, context: str) -> list:
    n = int(0.1 * RATE)
    chunks = [TTSAudioRawFrame(pcm[i : i + n].tobytes(), RATE, 1, context_id=context) for i in range(0, len(pcm), n)]
    return [TTSStartedFrame(context_id=context), *chunks, TTSStoppedFrame(context_id=context)]


def reply_started(session: LiveSession, segment: str) -> bool:
    return any(e.kind is Event.SPEAKING_START and e.info.get("segment") == segment for _, e in list(session.events))


async def converse(session: LiveSession, output, cut_after: float) -> dict[str, float]:
    """A user turn, thinking with a tool call, a reply played whole, a second reply interrupted
    ``cut_after`` seconds after it started; returns when (monotonic) each step was sent."""
    worker = PipelineWorker(Pipeline([output]), observers=[ConvodriveObserver(session)], cancel_on_idle_timeout=False)
    started = asyncio.Event()

    @worker.event_handler("on_pipeline_started")
    async def _started(worker, frame):
        started.set()

    marks: dict[str, float] = {}
    pcm = voice()

    async def script() -> None:
        await asyncio.wait_for(started.wait(), 10)
        await worker.queue_frame(UserStartedSpeakingFrame())
        silence = np.zeros(int(0.02 * RATE), np.int16).tobytes()
        for _ in range(40):
            await worker.queue_frame(InputAudioRawFrame(silence, RATE, 1))
            await asyncio.sleep(0.02)
        marks["turn_end"] = time.monotonic()
        await worker.queue_frame(UserStoppedSpeakingFrame())
        await worker.queue_frame(LLMFullResponseStartFrame())
        await worker.queue_frame(FunctionCallInProgressFrame(function_name="lookup", tool_call_id="1", arguments={}))
        await asyncio.sleep(1.0)
        marks["reply"] = time.monotonic()
        for frame in reply(pcm[: 2 * RATE], "c1"):
            await worker.queue_frame(frame)
        await asyncio.sleep(2.8)
        marks["reply2"] = time.monotonic()
        for frame in reply(pcm, "c2"):
            await worker.queue_frame(frame)
        # The cut comes while the second reply plays: on a busy machine its start may lag the queueing.
        deadline = time.monotonic() + 10.0
        while not reply_started(session, "c2") and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        await asyncio.sleep(cut_after)
        marks["cut"] = time.monotonic()
        await worker.queue_frame(InterruptionFrame())
        await asyncio.sleep(1.0)
        await worker.queue_frame(EndFrame())

    runner = WorkerRunner(handle_sigint=False)
    await runner.add_workers(worker)
    await asyncio.gather(runner.run(), script())
    return marks


def run(tmp_path, mode: str):
    session = LiveSession.open(
        mode=mode, backends=("record",), out_dir=tmp_path, generator_options={"phones": False}, self_rate=RATE
    )
    output = FakeSpeaker() if mode == "follower" else ConvodriveOutputTransport(session)
    try:
        marks = asyncio.run(converse(session, output, cut_after=1.0))
    finally:
        session.close()
    return session, output, marks


@pytest.mark.timeout(120)
def test_follower_behind_pipecats_output_transport(tmp_path):
    session, speaker, marks = run(tmp_path, "follower")
    order = kinds(session)
    expected = [Event.USER_TURN_START, Event.USER_TURN_END, Event.THINKING_START, Event.TOOL_START]
    assert order[:4] == expected
    assert order.index(Event.SPEAKING_START) > 3
    assert order[-2:] in ([Event.INTERRUPTED, Event.SPEAKING_END], [Event.SPEAKING_END, Event.INTERRUPTED]), [
        (e.kind.value, round(e.at, 3), e.info) for _, e in session.events[-6:]
    ]
    # Played-time anchors within one chunk of the fake speaker's writes.
    starts = [e for _, e in session.events if e.kind is Event.SPEAKING_START and "segment" in e.info]
    first_write = [w for w in speaker.writes if w > marks["reply"]][0]
    assert abs(starts[0].at - (session.time_at(first_write) + session.delay)) < CHUNK + 0.005
    # The interruption: the mouth is shut 100 ms after the cut shows (delay late).
    times, jaw = mouth(session)
    shown = marks["cut"] + session.delay
    assert jaw[(times > shown - 0.8) & (times < shown - 0.05)].max() > 0.2
    assert jaw[times > shown + 0.1].max() < CLOSED
    # Thinking: the look-away, mouth shut.
    eyes = eye_angle(tmp_path)
    think_at = [e.at for _, e in session.events if e.kind is Event.TOOL_START][0]
    thinking = slice(int((think_at + 0.3) * 30), int((starts[0].at - 0.05) * 30))
    before = slice(int((think_at - 0.7) * 30), int((think_at - 0.1) * 30))
    assert eyes[thinking].mean() > eyes[before].mean() + 8.0
    at_think = (times > marks["turn_end"] + session.delay + 0.1) & (times < first_write + session.delay - 0.05)
    assert jaw[at_think].max() < CLOSED


@pytest.mark.timeout(120)
def test_player_plays_through_the_convodrive_output_transport(tmp_path):
    session, _, marks = run(tmp_path, "player")
    order = kinds(session)
    assert order[:4] == [Event.USER_TURN_START, Event.USER_TURN_END, Event.THINKING_START, Event.TOOL_START]
    assert Event.SPEAKING_START in order and order[-1] is Event.INTERRUPTED
    played = session.speaker.samples()
    told = told_at(session, Event.INTERRUPTED)  # the transport's clear, after the frame's trip
    cut = int((session.speaker.position_at(told) + 0.03) * RATE)
    assert np.abs(played[cut:]).max() < 1e-6  # nothing of the cut reply plays after the cut
    heard = np.nonzero(np.abs(played) > 0.05)[0] / RATE
    first_heard = session.speaker.mono_of(heard[0])
    # Writes are paced to playing: no audio reached the session more than the write-ahead (and
    # the chunk being written, at most a 100 ms TTS frame) before it played, besides silence the feeder put
    # into a reply and reports (a starved feeder that found the voice late pads first). A starved writer only
    # makes it less.
    queued = list(session.voice.marks)
    assert len({m[0] for m in queued}) == 2
    came_before = max(session.speaker.mono_of(pos / RATE) - fed for _, pos, _, _, fed in queued)
    padded = session.feeder.stalled_samples / RATE
    assert came_before < session.write_ahead + 0.1 + 0.02 + padded
    times, jaw = mouth(session)
    assert jaw[(times > first_heard) & (times < first_heard + 1.5)].max() > 0.2
    assert jaw[times > told + 0.1].max() < CLOSED


def test_a_push_is_stamped_when_it_happened_not_when_the_observer_got_to_it():
    """Pipecat hands an observer its pushes through a queue of its own: on a busy machine they
    arrive late. The stamp is the push's own time on the worker's clock, whose start the earliest
    arrivals give."""
    from pipecat.observers.base_observer import FramePushed
    from pipecat.processors.frame_processor import FrameDirection

    observer = ConvodriveObserver(LiveSession.__new__(LiveSession))
    clock_start = time.monotonic() - 5.0

    def pushed(ago: float) -> FramePushed:
        ns = int((time.monotonic() - ago - clock_start) * 1e9)
        return FramePushed(None, None, EndFrame(), FrameDirection.DOWNSTREAM, ns)  # type: ignore[arg-type]

    assert abs(observer._pushed_at(pushed(0.0)) - time.monotonic()) < 0.005  # seen as it happened
    for ago in (0.08, 0.3):  # seen late
        assert abs(observer._pushed_at(pushed(ago)) - (time.monotonic() - ago)) < 0.005
    assert observer._pushed_at(FramePushed(None, None, EndFrame(), FrameDirection.DOWNSTREAM, 0)) == pytest.approx(
        time.monotonic(), abs=0.005
    ), "a processor without a clock yet: its arrival"


def test_the_chunk_pipecat_was_writing_when_cut_does_not_start_the_bot_again(tmp_path):
    """Pipecat's output transport plays out the chunk it took from its queue before an interruption
    came, and says the bot started speaking again (its stop comes 3 s later, by a fallback). That
    chunk is of the cleared reply: the session posts neither."""
    from pipecat.frames.frames import BotStartedSpeakingFrame, BotStoppedSpeakingFrame
    from pipecat.observers.base_observer import FramePushed
    from pipecat.processors.frame_processor import FrameDirection

    session = LiveSession.open(mode="follower", backends=("record",), out_dir=tmp_path, self_rate=RATE)
    observer = ConvodriveObserver(session)
    chunk = voice()[: int(0.1 * RATE)].tobytes()

    async def push(*frames) -> None:
        for frame in frames:
            await observer.on_push_frame(FramePushed(None, None, frame, FrameDirection.DOWNSTREAM, 0))  # type: ignore[arg-type]

    try:
        asyncio.run(push(TTSStartedFrame(context_id="c1"), TTSAudioRawFrame(chunk, RATE, 1, context_id="c1")))
        asyncio.run(push(BotStartedSpeakingFrame(), InterruptionFrame(), BotStoppedSpeakingFrame()))
        asyncio.run(push(BotStartedSpeakingFrame(), BotStoppedSpeakingFrame()))  # the chunk in hand, the fallback
        assert kinds(session)[-3:] == [Event.SPEAKING_START, Event.INTERRUPTED, Event.SPEAKING_END]
        asyncio.run(push(TTSStartedFrame(context_id="c2"), TTSAudioRawFrame(chunk, RATE, 1, context_id="c2")))
        asyncio.run(push(BotStartedSpeakingFrame()))  # the next reply starts the bot again
        assert kinds(session)[-2:] == [Event.SPEAKING_END, Event.SPEAKING_START]
    finally:
        session.close()
