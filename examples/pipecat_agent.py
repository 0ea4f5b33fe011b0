"""A Pipecat voice agent whose body convodrive moves: offline, no keys.

    python examples/pipecat_agent.py --backend dynamixel -B dynamixel.port=/dev/pts/3
    python examples/pipecat_agent.py --backend render        # avatar.mp4 with the voice

The user comes from a sound file (``--partner``, default the bundled dialogue's channel 1),
queued as a transport's input would push it; ``ScriptedBrain`` ends the user's turns by the
audio's level and answers each with a scripted line; ``EspeakTTS`` speaks it; convodrive plays the
voice (player mode, ``ConvodriveOutputTransport``, ``--speaker``) and moves the body, fed by
``ConvodriveObserver``. With keys, the same structure runs on real services:

    Pipeline([transport.input(), stt, user_aggregator, llm, tts, ConvodriveOutputTransport(live)])

with ``ScriptedBrain`` replaced by an STT service, ``LLMContextAggregatorPair(context)``'s user side
and an LLM service, and ``EspeakTTS`` by a TTS service; the input transport (``LocalAudioTransport``,
Daily, SmallWebRTC) replaces the file.
"""

from __future__ import annotations

import asyncio
import sys
import time

import numpy as np
from loguru import logger
from pipecat.frames.frames import (
    EndFrame,
    Frame,
    InputAudioRawFrame,
    InterruptionFrame,
    LLMFullResponseEndFrame,
    LLMFullResponseStartFrame,
    TextFrame,
    TTSAudioRawFrame,
    TTSStartedFrame,
    TTSStoppedFrame,
    UserStartedSpeakingFrame,
    UserStoppedSpeakingFrame,
)
from pipecat.pipeline.pipeline import Pipeline
from pipecat.pipeline.worker import PipelineWorker
from pipecat.processors.frame_processor import FrameDirection, FrameProcessor
from pipecat.workers.runner import WorkerRunner

from convodrive.agents import offline
from convodrive.agents.pipecat import ConvodriveObserver, ConvodriveOutputTransport
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.pipeline.session import LiveSession

RATE = ANALYSIS_RATE
BLOCK = int(offline.BLOCK * RATE)


class ScriptedBrain(FrameProcessor):
    """Stands in for STT, the user aggregator and the LLM: the user's turns from the audio's
    level, a scripted line for each, and a barge-in when the user speaks over the agent."""

    def __init__(self) -> None:
        super().__init__()
        self.turns = offline.TurnDetector()
        self.replies = offline.ScriptedReplies()
        self.bot_speaking = False

    async def process_frame(self, frame: Frame, direction: FrameDirection) -> None:
        await super().process_frame(frame, direction)
        await self.push_frame(frame, direction)
        if isinstance(frame, TTSStartedFrame):
            self.bot_speaking = True
        elif isinstance(frame, TTSStoppedFrame):
            self.bot_speaking = False
        if not isinstance(frame, InputAudioRawFrame):
            return
        change = self.turns.push(np.frombuffer(frame.audio, np.int16))
        if change == "start":
            if self.bot_speaking:
                await self.push_frame(InterruptionFrame())
            await self.push_frame(UserStartedSpeakingFrame())
        elif change == "end":
            await self.push_frame(UserStoppedSpeakingFrame())
            await self.push_frame(LLMFullResponseStartFrame())
            await asyncio.sleep(0.4)  # a model's time to first token
            await self.push_frame(TextFrame(self.replies.reply()))
            await self.push_frame(LLMFullResponseEndFrame())


class EspeakTTS(FrameProcessor):
    """Stands in for a TTS service: each ``TextFrame`` spoken by espeak-ng, in 20 ms chunks."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    async def process_frame(self, frame: Frame, direction: FrameDirection) -> None:
        await super().process_frame(frame, direction)
        if not isinstance(frame, TextFrame):
            await self.push_frame(frame, direction)
            return
        self.count += 1
        context = f"reply-{self.count}"
        pcm = await asyncio.to_thread(offline.synthesize, frame.text, RATE)
        await self.push_frame(TTSStartedFrame(context_id=context))
        for i in range(0, len(pcm) - BLOCK + 1, BLOCK):
            await self.push_frame(TTSAudioRawFrame(pcm[i : i + BLOCK].tobytes(), RATE, 1, context_id=context))
        await self.push_frame(TTSStoppedFrame(context_id=context))


async def converse(live: LiveSession, partner, seconds: float) -> None:
    pipeline = Pipeline([ScriptedBrain(), EspeakTTS(), ConvodriveOutputTransport(live)])
    worker = PipelineWorker(pipeline, observers=[ConvodriveObserver(live)], cancel_on_idle_timeout=False)

    async def microphone() -> None:
        """The file, 20 ms every 20 ms, then quiet until ``seconds`` (a transport's input)."""
        t0 = time.monotonic()
        for n in range(int(seconds / offline.BLOCK)):
            block = partner[n * BLOCK : (n + 1) * BLOCK]
            data = block.tobytes() if len(block) == BLOCK else bytes(2 * BLOCK)
            await worker.queue_frame(InputAudioRawFrame(data, RATE, 1))
            await asyncio.sleep(max(t0 + (n + 1) * offline.BLOCK - time.monotonic(), 0.0))
        await worker.queue_frame(EndFrame())

    runner = WorkerRunner(handle_sigint=False)
    await runner.add_workers(worker)
    await asyncio.gather(runner.run(), microphone())


def main(argv: list[str] | None = None) -> LiveSession:
    args = offline.agent_parser(__doc__.splitlines()[0]).parse_args(argv)
    logger.remove()  # Pipecat logs every frame's path at DEBUG
    logger.add(sys.stderr, level="WARNING")
    partner = offline.partner_audio(args.partner, args.channel)
    seconds = args.seconds if args.seconds is not None else len(partner) / RATE + 3.0
    live = offline.open_session(args)
    try:
        asyncio.run(converse(live, partner, seconds))
    finally:
        live.close()
    offline.finish(live, args.out)
    return live


if __name__ == "__main__":
    sys.exit(offline.run_main(main))
