"""Live sessions driven by the voice-agent frameworks (issue 33): prints JSON.

For each adapter (Pipecat's real pipeline worker, LiveKit's real no-room ``AgentSession``) and
mode (player: convodrive plays on a virtual speaker; follower: a fake speaker that takes each
20 ms chunk's duration and reports as the framework's sinks do), the framework's TTS hands over
espeak-ng replies in 20 ms chunks as fast as it makes them (a burst, as a TTS service does); the
adapters pace it (player mode) or the fake speaker does (follower). Every other reply is
interrupted 60 % in. The partner is 20 ms blocks of silence. Figures:

- ``first_chunk_to_dispatch_ms``: a reply's first TTS chunk leaving the framework's TTS -> the
  frame showing its first sample handed to the backends (player: the voice's look-ahead queue
  and the speaker; follower: the play report and ``delay``);
- ``partner_capture_to_sent_ms``: the partner's audio stamped on arrival -> the frame that first
  heard it sent to the backend (p50/p99), what ``convodrive live`` reports for a microphone;
- ``chunk_to_sent_ms``: each stretch of voice fed (player: at the paced write; follower: at its
  play report) -> its frame sent to the backend (p50/p99), from the session's own histogram;
- ``audio_motion_offset``: player mode, at the speaker: mouth onset at dispatch minus voice onset
  (median over speech onsets; negative = the mouth leads);
- ``interruption_to_mouth_shut_ms``: the interruption (follower: as shown, ``delay`` later) ->
  the first frame with jawOpen < 0.05.

    .venv/bin/python bench/bench_agent.py [--backend record] [--replies 4] [--adapters pipecat,livekit]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import tempfile
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bench.machine import cpu_name
from convodrive.agents.offline import synthesize
from convodrive.audio.source import ANALYSIS_RATE
from convodrive.eval.sync import level_db, mouth_onsets, pair_onsets, speech_onsets
from convodrive.generators.base import Event
from convodrive.pipeline.session import LiveSession

RATE = ANALYSIS_RATE
CHUNK = int(0.02 * RATE)
TEXTS = [
    "The train leaves at nine, and then we walk along the river.",
    "I looked it up: the museum opens at ten on Sundays, so we have time for breakfast.",
]


def partner(session: LiveSession, stop: threading.Event) -> None:
    block = np.zeros(CHUNK, np.int16).tobytes()
    while not stop.is_set():
        session.feed_partner(block, RATE)
        time.sleep(0.02)


class Script:
    """What to say and when each reply's first chunk left the TTS; interrupt odd replies."""

    def __init__(self, replies: int) -> None:
        self.voices = [synthesize(t, RATE) for t in TEXTS]
        self.replies = replies
        self.first_chunk: list[float] = []
        self.cuts: list[float] = []

    def voice(self, r: int) -> np.ndarray:
        return self.voices[r % len(self.voices)]

    def chunks(self, r: int) -> list[bytes]:
        pcm = self.voice(r)
        return [pcm[i : i + CHUNK].tobytes() for i in range(0, len(pcm) - CHUNK + 1, CHUNK)]

    def hold(self, r: int) -> float:
        """Seconds from a reply's start to its cut (odd replies) or to the next reply."""
        length = len(self.voice(r)) / RATE
        return 0.6 * length if r % 2 else length + 1.0


async def run_pipecat(live: LiveSession, script: Script) -> None:
    from pipecat.frames.frames import EndFrame, InterruptionFrame, TTSAudioRawFrame, TTSStartedFrame, TTSStoppedFrame
    from pipecat.pipeline.pipeline import Pipeline
    from pipecat.pipeline.worker import PipelineWorker
    from pipecat.transports.base_output import BaseOutputTransport
    from pipecat.transports.base_transport import TransportParams
    from pipecat.workers.runner import WorkerRunner

    from convodrive.agents.pipecat import ConvodriveObserver, ConvodriveOutputTransport

    class FakeSpeaker(BaseOutputTransport):
        def __init__(self) -> None:
            params = TransportParams(audio_out_enabled=True, audio_out_sample_rate=RATE, audio_out_end_silence_secs=0)
            super().__init__(params)

        async def start(self, frame):  # type: ignore[no-untyped-def]
            await super().start(frame)
            await self.set_transport_ready(frame)

        async def write_audio_frame(self, frame) -> bool:  # type: ignore[no-untyped-def]
            await asyncio.sleep(frame.num_frames / frame.sample_rate)
            return True

    output = ConvodriveOutputTransport(live) if live.player else FakeSpeaker()
    worker = PipelineWorker(Pipeline([output]), observers=[ConvodriveObserver(live)], cancel_on_idle_timeout=False)
    started = asyncio.Event()
    worker.event_handler("on_pipeline_started")(lambda *_: started.set())  # type: ignore[arg-type,func-returns-value]

    async def say() -> None:
        await asyncio.wait_for(started.wait(), 10)
        for r in range(script.replies):
            context = f"r{r}"
            await worker.queue_frame(TTSStartedFrame(context_id=context))
            script.first_chunk.append(time.monotonic())
            for chunk in script.chunks(r):
                await worker.queue_frame(TTSAudioRawFrame(chunk, RATE, 1, context_id=context))
            await worker.queue_frame(TTSStoppedFrame(context_id=context))
            await asyncio.sleep(script.hold(r))
            if r % 2:
                script.cuts.append(time.monotonic())
                await worker.queue_frame(InterruptionFrame())
                await asyncio.sleep(1.0)
        await worker.queue_frame(EndFrame())

    runner = WorkerRunner(handle_sigint=False)
    await runner.add_workers(worker)
    await asyncio.gather(runner.run(), say())


async def run_livekit(live: LiveSession, script: Script) -> None:
    from livekit import rtc
    from livekit.agents import Agent, AgentSession, llm
    from livekit.agents.voice import io

    from convodrive.agents.livekit import ConvodriveAudioOutput, attach

    class NoLLM(llm.LLM):
        def chat(self, **kwargs):  # type: ignore[no-untyped-def,override]
            raise NotImplementedError

    class FakeSpeaker(io.AudioOutput):
        def __init__(self) -> None:
            super().__init__(label="fake", capabilities=io.AudioOutputCapabilities(pause=True), sample_rate=RATE)
            self.started: float | None = None
            self.pushed = 0.0

        async def capture_frame(self, frame: rtc.AudioFrame) -> None:
            await super().capture_frame(frame)
            if self.started is None:
                self.started = time.time()
                self.on_playback_started(created_at=self.started)
            await asyncio.sleep(frame.duration)
            self.pushed += frame.duration

        def _finish(self, interrupted: bool) -> None:
            if self.started is not None:
                self.on_playback_progressed(started_at=self.started, offset=0.0, duration=self.pushed)
                self.on_playback_finished(playback_position=self.pushed, interrupted=interrupted)
            self.started, self.pushed = None, 0.0

        def flush(self) -> None:
            super().flush()
            asyncio.get_running_loop().call_soon(self._finish, False)

        def clear_buffer(self) -> None:
            self._finish(True)

    class Speaks(Agent):
        def __init__(self) -> None:
            super().__init__(instructions="-")
            self.r = 0

        async def llm_node(self, chat_ctx, tools, model_settings):  # type: ignore[no-untyped-def,override]
            yield TEXTS[self.r % len(TEXTS)]

        async def tts_node(self, text, model_settings):  # type: ignore[no-untyped-def,override]
            async for _ in text:
                pass
            script.first_chunk.append(time.monotonic())
            for chunk in script.chunks(self.r):
                yield rtc.AudioFrame(chunk, RATE, 1, CHUNK)

    session = AgentSession(vad=None, llm=NoLLM(), turn_handling={"turn_detection": "manual"})
    session.output.audio = ConvodriveAudioOutput(live) if live.player else FakeSpeaker()
    agent = Speaks()
    await session.start(agent, record=False)
    attach(session, live)
    for r in range(script.replies):
        agent.r = r
        handle = session.generate_reply(user_input="go on")
        await asyncio.sleep(script.hold(r))
        if r % 2:
            script.cuts.append(time.monotonic())
            session.interrupt()
        await handle.wait_for_playout()
        await asyncio.sleep(0.3 if r % 2 else 0.0)
    await asyncio.sleep(0.5)
    await session.aclose()


ADAPTERS: dict[str, Callable[[LiveSession, Script], Any]] = {"pipecat": run_pipecat, "livekit": run_livekit}


def run(adapter: str, mode: str, backend: str, replies: int) -> dict:
    script = Script(replies)
    with tempfile.TemporaryDirectory() as out:
        s = LiveSession.open(
            mode=mode, backends=(backend,), out_dir=out, self_rate=RATE, generator_options={"phones": False}
        )
        stop = threading.Event()
        threading.Thread(target=partner, args=(s, stop), daemon=True).start()
        while s.time_at(time.monotonic()) is None:
            time.sleep(0.01)
        try:
            asyncio.run(ADAPTERS[adapter](s, script))
        finally:
            stop.set()
            s.close()
        return figures(adapter, s, script, backend)


def figures(adapter: str, s: LiveSession, script: Script, backend: str) -> dict:
    frames = list(s.frames)
    index = np.array([f[0] for f in frames])
    times = np.array([f[1] for f in frames])
    jaw = np.array([f[2] for f in frames])
    starts = [e.at for _, e in s.events if e.kind is Event.SPEAKING_START and "segment" in e.info]
    first = []
    for t_chunk, at in zip(script.first_chunk, starts, strict=False):
        k = np.nonzero(index >= int(round(at * 30)))[0]
        if len(k):
            first.append(1000.0 * (times[k[0]] - t_chunk))
    shown = [c + (0.0 if s.player else s.delay) for c in script.cuts]
    shut = []
    for c in shown:
        after = np.nonzero((times > c) & (jaw < 0.05))[0]
        if len(after):
            shut.append(round(1000.0 * (times[after[0]] - c), 1))
    report = s.figures()
    result: dict[str, Any] = {
        "adapter": adapter,
        "mode": s.request.mode,
        "first_chunk_to_dispatch_ms": [round(x, 1) for x in first],
        "chunk_to_sent_ms": report["latency_ms"]["self_fed_to_sent"].get(backend),
        "partner_capture_to_sent_ms": report["latency_ms"]["partner_capture_to_sent"].get(backend),
        "interruption_to_mouth_shut_ms": shut,
        "self_lead_ms": report["latency_ms"]["self_lead"],
        "delay_ms": report["latency_ms"]["follower_delay"],
    }
    if s.player and s.speaker is not None and hasattr(s.speaker, "samples"):
        played = s.speaker.samples()
        onsets = speech_onsets(level_db(played, RATE))
        audio_mono = np.array([s.speaker.mono_of(t) for t in onsets])
        motion_mono = times[mouth_onsets(jaw)] if len(jaw) else np.zeros(0)
        result["audio_motion_offset"] = pair_onsets(audio_mono, motion_mono).summary()
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="record")
    parser.add_argument("--replies", type=int, default=4)
    parser.add_argument("--adapters", default="pipecat,livekit")
    args = parser.parse_args()
    runs = [run(a, m, args.backend, args.replies) for a in args.adapters.split(",") for m in ("player", "follower")]
    print(json.dumps({"cpu": cpu_name(), "backend": args.backend, "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
