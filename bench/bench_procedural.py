"""Benchmark of the procedural generator: declared and measured look-ahead, real-time factor.

Runs on one core (thread pools limited to one thread, the process pinned to one CPU where the OS
allows) on the bundled dialogue (samples/dialogue.wav), or on a synthesised one if it is missing.
Prints JSON. Usage: .venv/bin/python bench/bench_procedural.py [AUDIO] [--repeats N]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def bundled_or_synthesised() -> Path:
    path = REPO / "samples" / "dialogue.wav"
    if path.exists():
        return path
    from convodrive.audio.synth import PARTNER, SELF, Turn, synthesize_dialogue

    out = Path(tempfile.mkdtemp()) / "dialogue.wav"
    synthesize_dialogue([
        Turn(SELF, "Hi there. Did you get a chance to look at the robot head yesterday?"),
        Turn(PARTNER, "I did. It was moving its eyes really smoothly.", "en-us+f3", 175),
        Turn(SELF, "Great. The jaw follows the voice now, but the lips are still a bit stiff."),
        Turn(PARTNER, "Maybe we can use the visemes from the speech recogniser.", "en-us+f3", 175),
    ], out)
    return out


def best_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def measured_latency_ms(gen, audio) -> float:
    """Black-box look-ahead: for each frame, how much audio past the frame's end had been pulled
    from the source when the stream yielded it (10 ms chunks; the final flush is excluded)."""
    from convodrive.audio.source import ANALYSIS_RATE

    chunks = list(audio.chunks(160))
    pulled = [0]

    def source():
        for chunk in chunks:
            pulled[0] += len(chunk)
            yield chunk

    total = sum(len(c) for c in chunks)
    worst = 0.0
    for k, _frame in enumerate(gen.stream(source(), seed=0)):
        if pulled[0] < total:
            worst = max(worst, pulled[0] / ANALYSIS_RATE - (k + 1) / 30.0)
    return 1000.0 * worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("audio", nargs="?", help="dialogue audio (default: samples/dialogue.wav)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    pinned = False
    if hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
            pinned = True
        except OSError:
            pass

    from convodrive.audio.phones import pocketsphinx_available
    from convodrive.audio.source import AudioSource
    from convodrive.generators.procedural import ProceduralGenerator

    path = Path(args.audio) if args.audio else bundled_or_synthesised()
    audio = AudioSource(path).read_all()
    result: dict = {
        "audio": str(path.relative_to(REPO) if path.is_relative_to(REPO) else path),
        "duration_s": round(audio.duration, 3),
        "one_core": {"threads": 1, "pinned_to_one_cpu": pinned},
    }
    configs = {"phones": {"phones": True}, "spectral_only": {"phones": False}}
    if not pocketsphinx_available():
        configs.pop("phones")
    for label, options in configs.items():
        gen = ProceduralGenerator(options)
        gen.generate(audio, seed=0)  # warm up: loads the phone model once per process
        offline = best_time(lambda: gen.generate(audio, seed=0), args.repeats)
        streamed = best_time(lambda: sum(1 for _ in gen.stream(audio.chunks(), seed=0)), args.repeats)
        takes = best_time(lambda: gen.generate(audio, seed=0, num_samples=4), 1)
        result[label] = {
            "options": options,
            "lookahead_frames": gen.lookahead_frames,
            "lookahead_ms": round(1000.0 * gen.lookahead_frames / 30.0, 1),
            "measured_max_latency_ms": round(measured_latency_ms(gen, audio), 1),
            "generate_realtime_factor": round(audio.duration / offline, 1),
            "stream_100ms_chunks_realtime_factor": round(audio.duration / streamed, 1),
            "generate_4_takes_realtime_factor": round(audio.duration / takes, 1),
        }
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
