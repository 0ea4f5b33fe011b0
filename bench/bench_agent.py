"""Live sessions as a voice agent drives them (issue 33): prints JSON.

For each mode (player on a virtual speaker; follower behind a fake speaker reporting 40 ms
chunks), a speech synthesiser faster than real time feeds replies (espeak-ng); the partner is 20
ms blocks of silence. Figures: TTS chunk fed -> frame sent to the backend (p50/p99; in player
mode this includes the voice's queue to the speaker), the audio-motion offset at the speaker in
player mode (median over speech onsets: mouth onset at dispatch minus voice onset at the
speaker), and interruption -> the first frame with the mouth shut (jawOpen < 0.05).

    .venv/bin/python bench/bench_agent.py [--backend record] [--replies 4]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import threading
import time

import numpy as np

from convodrive.audio.source import ANALYSIS_RATE
from convodrive.audio.synth import speak
from convodrive.eval.sync import level_db, mouth_onsets, pair_onsets, speech_onsets
from convodrive.pipeline.session import LiveSession

RATE = ANALYSIS_RATE
TEXTS = [
    "The train leaves at nine, and then we walk along the river.",
    "I looked it up: the museum opens at ten on Sundays, so we have time for breakfast.",
]


def cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def partner(session: LiveSession, stop: threading.Event) -> None:
    block = np.zeros(int(0.02 * RATE), np.int16).tobytes()
    while not stop.is_set():
        session.feed_partner(block, RATE)
        time.sleep(0.02)


def play_follower(session: LiveSession, pcm: np.ndarray, segment: str, until: float) -> None:
    n = int(0.04 * RATE)
    t0 = time.monotonic()
    for k, i in enumerate(range(0, len(pcm), n)):
        time.sleep(max(t0 + (k + 1) * 0.04 - time.monotonic(), 0))
        if time.monotonic() > until:
            return
        session.self_played(segment, i / RATE, at=time.monotonic() - 0.04)


def run(mode: str, backend: str, replies: int) -> dict:
    voices = [(np.clip(speak(t, sample_rate=RATE), -1, 1) * 32767).astype(np.int16) for t in TEXTS]
    with tempfile.TemporaryDirectory() as out:
        s = LiveSession.open(
            mode=mode, backends=(backend,), out_dir=out, self_rate=RATE, generator_options={"phones": False}
        )
        stop = threading.Event()
        threading.Thread(target=partner, args=(s, stop), daemon=True).start()
        while s.time_at(time.monotonic()) is None:
            time.sleep(0.01)
        cuts = []
        for r in range(replies):
            pcm = voices[r % len(voices)]
            seg = f"r{r}"
            for i in range(0, len(pcm), int(0.02 * RATE)):
                s.feed_self(pcm[i : i + int(0.02 * RATE)].tobytes(), RATE, segment=seg)
            interrupt = r % 2 == 1
            length = len(pcm) / RATE
            until = time.monotonic() + (length * 0.6 if interrupt else length + 1.0)
            if mode == "follower":
                play_follower(s, pcm, seg, until)
            time.sleep(max(until - time.monotonic(), 0))
            if interrupt:
                cuts.append(time.monotonic())
                s.clear_self()
            else:
                s.end_self(seg)
            time.sleep(1.0)
        stop.set()
        s.close()
        figures = s.figures()
        times = np.array([f[1] for f in s.frames])
        jaw = np.array([f[2] for f in s.frames])
        shown = [c + (0.0 if mode == "player" else s.delay) for c in cuts]
        shut = []
        for c in shown:
            after = np.nonzero((times > c) & (jaw < 0.05))[0]
            if len(after):
                shut.append(1000.0 * (times[after[0]] - c))
        result = {
            "mode": mode,
            "backend": backend,
            "tts_chunk_to_sent_ms": figures["latency_ms"]["self_fed_to_sent"].get(backend),
            "partner_capture_to_sent_ms": figures["latency_ms"]["partner_capture_to_sent"].get(backend),
            "interruption_to_mouth_shut_ms": [round(x, 1) for x in shut],
        }
        if mode == "player":
            played = s.speaker.samples()
            onsets = speech_onsets(level_db(played / 1.0, RATE))
            audio_mono = np.array([s.speaker.mono_of(t) for t in onsets])
            motion_mono = times[mouth_onsets(jaw)] if len(jaw) else np.zeros(0)
            result["audio_motion_offset"] = pair_onsets(audio_mono, motion_mono).summary()
        else:
            result["delay_ms"] = figures["latency_ms"]["follower_delay"]
        return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="record")
    parser.add_argument("--replies", type=int, default=4)
    args = parser.parse_args()
    results = [run(m, args.backend, args.replies) for m in ("player", "follower")]
    print(json.dumps({"cpu": cpu_name(), "adapter": "library (no framework)", "runs": results}, indent=1))


if __name__ == "__main__":
    main()
