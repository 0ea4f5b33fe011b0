"""Benchmark of the probtalk generator on this machine's CPU (ONNX Runtime + NumPy).

Prints JSON with
- ``window_fps``: frames per second for one 180-frame window (30 known context frames, one take)
  at T = 1, 2, 4, 8, 16 MaskGIT passes, for each preset (``paper``, ``small``) and precision
  (fp32, int8), with ``--threads`` ONNX Runtime threads (the paper's Table 4 axis; its T = 8
  figure is 1067 frames/s on a TITAN Xp). Speed does not depend on the weights, so the graphs
  are exported from freshly initialised networks (``--model DIR`` times a trained folder too);
- ``window_fps_per_cpu_second``: the same with one thread, frames per second of CPU time (what
  one core does, whatever else the machine runs: quote it beside the wall-clock figures when the
  machine is shared);
- ``stage_ms``: where one T = 8 window's time goes (memory, MaskGIT passes, decoder, refiner);
- ``file_rtf_one_thread``: real-time factor of ``generate`` in file mode on ``--seconds`` of
  audio with one thread (the ``small`` preset must reach 10);
- ``live``: real-time factor and latency of live mode (look-ahead plus the window's compute);
- ``samples_4``: seconds for 4 takes in one batched pass against 4 single ones;
- the machine's load average before and after (the machine may be shared: quote it).

Every figure runs the refiner, though the generator leaves it off unless asked. The window figures
draw the codes once (the paper's pipeline); the file and live figures run the generator's default
second draw for the face (``face_temperature``) as well, the slowest configuration a user runs.

Usage: .venv/bin/python -m bench.bench_probtalk [--presets paper,small] [--threads 2] [--repeats 5] [--model DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench.learned import speech_like, untrained_folder
from convodrive.generators.probtalk.generator import ProbTalkGenerator
from convodrive.motion import representation as rep

ITERATIONS = (1, 2, 4, 8, 16)
WINDOW, CONTEXT = 180, 30


def _window_inputs(gen: ProbTalkGenerator, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    audio = (rng.standard_normal((WINDOW, 2, gen.mel_spec.bands)) * 3 - 8).astype(np.float32)
    context = rng.standard_normal((1, CONTEXT, rep.FEATURE_DIM)).astype(np.float32)
    return audio, context


def _generator(folder: Path, **options: Any) -> ProbTalkGenerator:
    """The generator on the CPU with the refiner on, one thread unless ``options`` say otherwise."""
    return ProbTalkGenerator({"model": str(folder), "threads": 1, "device": "cpu", "refine": True, **options})


def window_seconds(
    gen: ProbTalkGenerator, repeats: int, takes: int = 1, clock: Callable[[], float] = time.perf_counter
) -> float:
    """Median seconds of one window (after a warm-up run), on ``clock`` (wall by default)."""
    audio, context = _window_inputs(gen)
    context = np.repeat(context, takes, axis=0)
    times = []
    for r in range(repeats + 1):
        rngs = [np.random.default_rng([r, k]) for k in range(takes)]
        started = clock()
        gen.run_window(audio, context, rngs)
        times.append(clock() - started)
    return statistics.median(times[1:])


def stage_ms(gen: ProbTalkGenerator, repeats: int) -> dict[str, float]:
    """Milliseconds of each graph call of one window (T passes of the step graph summed)."""
    audio, context = _window_inputs(gen)
    spent: dict[str, list[float]] = {}
    graphs = {"memory": gen.memory, "step": gen.step, "decoder": gen.decoder, "refiner": gen.refiner}

    class Timed:
        def __init__(self, name: str, graph: Any) -> None:
            self.name, self.graph = name, graph

        def __call__(self, *args: Any, **kwargs: Any) -> Any:
            started = time.perf_counter()
            result = self.graph(*args, **kwargs)
            spent.setdefault(self.name, []).append(time.perf_counter() - started)
            return result

    for name, graph in graphs.items():
        if graph is not None:
            setattr(gen, name, Timed(name, graph))
    try:
        totals: list[float] = []
        per_graph: dict[str, list[float]] = {}
        for r in range(repeats + 1):
            spent.clear()
            started = time.perf_counter()
            gen.run_window(audio, context, [np.random.default_rng(r)])
            if r:
                totals.append(time.perf_counter() - started)
                for name, values in spent.items():
                    per_graph.setdefault(name, []).append(sum(values))
    finally:
        for name, graph in graphs.items():
            if graph is not None:
                setattr(gen, name, graph)
    out = {name: round(statistics.median(v) * 1000, 2) for name, v in per_graph.items()}
    out["total"] = round(statistics.median(totals) * 1000, 2)
    out["numpy_and_glue"] = round(out["total"] - sum(v for k, v in out.items() if k != "total"), 2)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", default="paper,small")
    parser.add_argument("--precisions", default="fp32,int8")
    parser.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads for the window figures")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=60.0, help="audio for the real-time factors")
    parser.add_argument("--model", type=Path, default=None, help="also time this trained model folder")
    args = parser.parse_args()
    out: dict[str, Any] = {"load_before": [round(x, 2) for x in os.getloadavg()], "cpus": os.cpu_count()}
    out["window"] = {"frames": WINDOW, "context": CONTEXT, "takes": 1, "threads": args.threads}
    folders: dict[str, Path] = {}
    with tempfile.TemporaryDirectory(prefix="bench_probtalk_") as tmp:
        for preset in args.presets.split(","):
            for precision in args.precisions.split(","):
                folders[f"{preset} {precision}"] = untrained_folder("probtalk", preset, precision == "int8", Path(tmp))
        if args.model is not None:
            folders["trained " + args.model.name] = args.model
        fps: dict[str, dict[str, float]] = {}
        per_cpu: dict[str, dict[str, float]] = {}
        stages: dict[str, dict[str, float]] = {}
        for label, folder in folders.items():
            fps[label], per_cpu[label] = {}, {}
            for t in ITERATIONS:
                gen = _generator(folder, iterations=t, threads=args.threads, face_temperature=0)
                fps[label][f"T={t}"] = round(WINDOW / window_seconds(gen, args.repeats), 1)
                one = _generator(folder, iterations=t, face_temperature=0)
                per_cpu[label][f"T={t}"] = round(WINDOW / window_seconds(one, args.repeats, clock=time.process_time), 1)
                if t == 8:
                    stages[label] = stage_ms(gen, args.repeats)
        out["window_fps"] = fps
        out["window_fps_per_cpu_second"] = per_cpu
        out["stage_ms_T8"] = stages
        audio = speech_like(args.seconds)
        rtf: dict[str, Any] = {}
        live: dict[str, Any] = {}
        batched: dict[str, Any] = {}
        for label, folder in folders.items():
            if label.startswith("paper"):
                continue
            gen = _generator(folder)
            started = time.perf_counter()
            gen.generate(audio, seed=0)
            rtf[label] = round(args.seconds / (time.perf_counter() - started), 1)
            lgen = _generator(folder, mode="live")
            started = time.perf_counter()
            lgen.generate(audio, seed=0)
            live_rtf = args.seconds / (time.perf_counter() - started)
            compute = window_seconds(lgen, args.repeats)
            live[label] = {
                "rtf_one_thread": round(live_rtf, 1),
                "window_ms": round(compute * 1000, 1),
                "lookahead_s": round(lgen.lookahead_frames / 30, 3),
                "latency_s": round(lgen.lookahead_frames / 30 + compute, 3),
            }
            one = window_seconds(gen, args.repeats, takes=1)
            four = window_seconds(gen, args.repeats, takes=4)
            batched[label] = {
                "one_take_s": round(one, 4),
                "four_takes_batched_s": round(four, 4),
                "four_singles_s": round(4 * one, 4),
            }
        out["file_rtf_one_thread"] = rtf
        out["live"] = live
        out["samples_4"] = batched
    out["load_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
