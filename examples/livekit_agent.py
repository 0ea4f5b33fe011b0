"""A LiveKit Agents voice agent whose body convodrive moves: offline, no server, no keys.

    python examples/livekit_agent.py --backend dynamixel -B dynamixel.port=/dev/pts/3
    python examples/livekit_agent.py --backend render        # avatar.mp4 with the voice

The user comes from a sound file (``--partner``, default the bundled dialogue's channel 1),
paced as a microphone; LiveKit's default VAD (local Silero) hears the user speak and a level-based
turn detector ends the user's turns; a scripted line
answers each; espeak-ng speaks it; convodrive plays the voice (player mode, ``--speaker``) and
moves the body. With keys, the same structure runs on real services: give ``AgentSession``
``stt=``, ``llm=``, ``tts=`` and ``vad=`` plugins (and ``turn_handling`` with a turn detector),
drop the two node overrides, and start it with ``room=ctx.room`` inside a job entrypoint
(``session.input.audio`` then comes from the room; keep ``ConvodriveAudioOutput`` so the robot
plays the voice).
"""

from __future__ import annotations

import asyncio
import sys
import time

from livekit import rtc
from livekit.agents import Agent, AgentSession, llm
from livekit.agents.voice import io

from convodrive.agents import offline
from convodrive.agents.livekit import ConvodriveAudioOutput, attach
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.generators.base import Event
from convodrive.pipeline.session import LiveSession

RATE = ANALYSIS_RATE
BLOCK = int(offline.BLOCK * RATE)


class NoLLM(llm.LLM):
    """LiveKit wants an LLM to generate a reply; ``Scripted.llm_node`` answers instead."""

    def chat(self, **kwargs):  # type: ignore[override]
        raise NotImplementedError("the scripted agent answers in llm_node")


class FileMicrophone(io.AudioInput):
    """The user's audio from a file, a 20 ms frame every 20 ms (a room's track in a real agent)."""

    def __init__(self, pcm, on_turn) -> None:
        super().__init__(label="file-microphone")
        self.pcm, self.on_turn = pcm, on_turn
        self.turns = offline.TurnDetector()
        self.n = 0
        self.t0: float | None = None

    async def __anext__(self) -> rtc.AudioFrame:
        self.t0 = self.t0 or time.monotonic()
        await asyncio.sleep(max(self.t0 + (self.n + 1) * offline.BLOCK - time.monotonic(), 0.0))
        i = self.n * BLOCK
        self.n += 1
        block = self.pcm[i : i + BLOCK]
        if len(block) < BLOCK:  # the file ended: the user is quiet
            block = bytes(2 * BLOCK)
        else:
            change = self.turns.push(block)
            if change is not None:
                self.on_turn(change)
            block = block.tobytes()
        return rtc.AudioFrame(block, RATE, 1, BLOCK)


class Scripted(Agent):
    """Answers each user turn with a scripted line, spoken by espeak-ng (``llm_node`` and
    ``tts_node`` stand in for an LLM and a TTS service)."""

    def __init__(self) -> None:
        super().__init__(instructions="Answer briefly.")
        self.replies = offline.ScriptedReplies()

    async def llm_node(self, chat_ctx, tools, model_settings):  # type: ignore[override]
        await asyncio.sleep(0.4)  # a model's time to first token
        yield self.replies.reply()

    async def tts_node(self, text, model_settings):  # type: ignore[override]
        line = "".join([part async for part in text])
        pcm = await asyncio.to_thread(offline.synthesize, line, RATE)
        for i in range(0, len(pcm) - BLOCK + 1, BLOCK):
            yield rtc.AudioFrame(pcm[i : i + BLOCK].tobytes(), RATE, 1, BLOCK)


async def converse(live: LiveSession, partner, seconds: float) -> None:
    session = AgentSession(llm=NoLLM(), turn_handling={"turn_detection": "manual"})

    def on_turn(change: str) -> None:
        # The user's speech start and stop come from LiveKit's own local VAD (user_state_changed,
        # which attach maps); the turn's end would come from STT's final transcript.
        if change == "start":
            if session.agent_state == "speaking":
                session.interrupt()  # barge-in
        else:
            live.event(Event.USER_TURN_END)
            session.generate_reply(user_input="(the user's turn)")

    session.input.audio = FileMicrophone(partner, on_turn)
    session.output.audio = ConvodriveAudioOutput(live)  # before start: the robot plays the voice
    await session.start(Scripted(), record=False)
    attach(session, live)
    await asyncio.sleep(seconds)
    await session.aclose()


def main(argv: list[str] | None = None) -> LiveSession:
    args = offline.agent_parser(__doc__.splitlines()[0]).parse_args(argv)
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
