"""Benchmark of the a2p generator on this machine's CPU (ONNX Runtime + NumPy).

Prints JSON with
- ``rtf``: real-time factor of ``generate`` (lip, face, guide poses, body: all of it) on
  ``--seconds`` of speech-like dialogue (20 s: the reference's longest input), for each preset
  (``paper``, ``small``) and precision (fp32, int8): the generator's defaults (DDIM, 10 steps for
  the body and 50 for the face, guidance on the face and on the body's audio), the distilled sampler,
  DPM-Solver++ on the teachers (``dpm``: its defaults, 4 body and 8 face steps), and DDIM at
  ``--ddim`` steps for both (classifier-free guidance on both, both halves one batch, as the
  reference samples), ``--threads`` ONNX Runtime threads.
  Speed does not depend on the weights, so the graphs are exported from fresh networks
  (``--model DIR``, repeatable, times trained folders too; ``--presets ""`` times only those). The reference: 0.062x on these 2 cores at DDIM 100
  with guidance; targets: ``paper`` distilled >= 1x, ``small`` distilled >= 5x;
- ``guide_80_tokens_s``: the guide transformer's time for 80 tokens (20 s of guide poses), in
  torch: each token by re-running the whole prefix and re-encoding its audio (as the reference
  samples), and one cached step a token; and through the ONNX step graph with its cache;
- ``live``: look-ahead, a window's compute (median and worst) and their sum, the latency (target
  <= 0.5 s), with the defaults of live mode (DDIM, 20 face steps), the distilled sampler and dpm;
- ``long`` (with ``--model``, the first one, ``--long-minutes`` of the bundled dialogue looped): the largest frame
  change (pose and face) at a window seam against the largest inside windows, and the peak of
  traced memory after the first minute against at the end (constant memory);
- the machine's load average before and after (it may be shared: quote it).

Usage: .venv/bin/python -m bench.bench_a2p [--presets paper,small] [--ddim 10,25,100] [--threads 2]
       [--model DIR ... [--long-minutes 10]]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.learned import speech_like, untrained_folder
from convodrive.audio.source import DyadicAudio
from convodrive.generators.a2p.generator import A2PGenerator
from convodrive.neural.autoregressive import KVCache, sample_tokens

TOKENS = 80


def rtf(folder: Path, audio: DyadicAudio, threads: int, **options: Any) -> float:
    gen = A2PGenerator({"model": str(folder), "threads": threads, "device": "cpu", **options})
    started = time.perf_counter()
    gen.generate(audio, seed=0)
    return round(audio.duration / (time.perf_counter() - started), 3)


def live_latency(folder: Path, audio: DyadicAudio, threads: int, **options: Any) -> dict[str, float]:
    """Look-ahead plus a live window's compute, timed on every window of a stream."""
    gen = A2PGenerator({"model": str(folder), "threads": threads, "device": "cpu", "mode": "live", **options})
    spent: list[float] = []
    run_window = gen.run_window

    def timed(*args: Any, **kwargs: Any) -> Any:
        started = time.perf_counter()
        out = run_window(*args, **kwargs)
        spent.append(time.perf_counter() - started)
        return out

    gen.run_window = timed  # type: ignore[method-assign]
    for _ in gen.stream(audio.chunks(), seed=0):
        pass
    lookahead = gen.lookahead_frames / 30
    median, worst = statistics.median(spent[1:]), max(spent[1:])
    return {
        "lookahead_s": round(lookahead, 3),
        "hop_s": round(gen.plan.hop / 30, 3),
        "window_ms_median": round(median * 1000, 1),
        "window_ms_max": round(worst * 1000, 1),
        "latency_s": round(lookahead + median, 3),
        "latency_worst_s": round(lookahead + worst, 3),
    }


def guide_torch(preset: str) -> dict[str, float]:
    """Seconds for 80 guide tokens in torch, one thread (more spin and wait on a shared machine:
    9 s instead of 0.3 s measured here): the whole prefix (and its audio) re-run at every token,
    against one cached step a token (argmax picks: sampling costs the same in both)."""
    import torch

    from convodrive.models.a2p import A2P
    from convodrive.training.registry import get_preset, get_recipe

    torch.set_num_threads(1)
    recipe = get_recipe("a2p")
    config = recipe.model_config(get_preset(recipe, preset)[1].model)
    guide = A2P(config, 80, 6, "guide").guide
    assert guide is not None
    guide.eval()
    levels, span = config.vq_levels, config.guide_audio_span
    seconds = TOKENS // levels
    chunks = torch.randn(1, span - 1 + seconds, 30, 160)
    speaker = torch.zeros(1, dtype=torch.long)
    with torch.no_grad():
        started = time.perf_counter()
        tokens = torch.full((1, 1), guide.start_token, dtype=torch.long)
        for n in range(TOKENS):
            memory = guide.audio_memory(chunks[:, : span + n // levels])
            logits = guide(tokens, memory, speaker)[:, -1]
            tokens = torch.cat([tokens, logits.argmax(-1, keepdim=True)], dim=1)
        rerun = time.perf_counter() - started
        started = time.perf_counter()
        memory = guide.audio_memory(chunks)
        keys, values = guide.empty_cache(1)
        token = torch.full((1, 1), guide.start_token, dtype=torch.long)
        for n in range(TOKENS):
            second = n // levels
            band = memory[:, second : second + span]
            logits, keys, values = guide.step(token, torch.full((1, 1), n), band, keys, values, speaker)
            keys, values = keys[:, :, :, -(config.guide_band - 1) :], values[:, :, :, -(config.guide_band - 1) :]
            token = logits.argmax(-1, keepdim=True)
        cached = time.perf_counter() - started
    return {"torch_full_prefix_rerun": round(rerun, 3), "torch_kv_cache": round(cached, 4)}


def guide_onnx(folder: Path, threads: int) -> float:
    """Seconds for 80 guide tokens through the runtime's step graph, cache and nucleus sampling."""
    gen = A2PGenerator({"model": str(folder), "threads": threads, "device": "cpu"})
    guides = gen.guides
    state = guides.state(1)
    band = np.repeat(guides.silent_second[None, None], guides.span, axis=1)
    step = guides.step_function(band)
    rng = [np.random.default_rng(0)]
    started = time.perf_counter()
    for _ in range(TOKENS // guides.levels):
        sample_tokens(step, state.cache, guides.levels, guides.top_p, rng, guides.temperature)
    assert isinstance(state.cache, KVCache)
    return round(time.perf_counter() - started, 4)


def long_run(folder: Path, minutes: float) -> dict[str, Any]:
    """Seams and memory of ``minutes`` of the bundled dialogue, looped, in file mode."""
    import tracemalloc

    from convodrive.audio.source import AudioSource
    from convodrive.samples import bundled_dialogue

    one = AudioSource(bundled_dialogue()).read_all()
    times = int(np.ceil(minutes * 60 / one.duration))
    audio = DyadicAudio(np.tile(one.self_voice, times), np.tile(one.other_voice, times))
    gen = A2PGenerator({"model": str(folder), "device": "cpu"})
    hop = gen.plan.hop
    worst = {f"{part}_{where}": 0.0 for part in ("pose", "face") for where in ("seam", "inside")}
    previous: tuple[np.ndarray, np.ndarray] | None = None
    peaks = {}
    tracemalloc.start()
    for k, frame in enumerate(gen.stream(audio.chunks(), seed=0)):
        now = (frame.pose.reshape(-1).copy(), frame.face.copy())
        if previous is not None:
            where = "seam" if k % hop == 0 else "inside"  # frame k is a window's first new frame
            for part, a, b in zip(("pose", "face"), previous, now):
                worst[f"{part}_{where}"] = max(worst[f"{part}_{where}"], float(np.abs(b - a).max()))
        previous = now
        if k == 30 * 60:
            peaks["first_minute"] = tracemalloc.get_traced_memory()[1]
    peaks["end"] = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    out: dict[str, Any] = {"seconds": round(audio.duration, 1), "windows": gen.windows, "hop": hop}
    out["max_frame_change"] = {k: round(v, 5) for k, v in worst.items()}
    out["traced_peak_mb"] = {k: round(v / 1e6, 2) for k, v in peaks.items()}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", default="paper,small")
    parser.add_argument("--precisions", default="fp32,int8")
    parser.add_argument("--ddim", default="10,25,100", help="DDIM step counts to time (comma-separated)")
    parser.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads per graph")
    parser.add_argument("--seconds", type=float, default=20.0, help="dialogue length for the real-time factors")
    parser.add_argument(
        "--model", type=Path, action="append", default=[], help="also time this trained model folder (repeatable)"
    )
    parser.add_argument("--long-minutes", type=float, default=0.0, help="seams and memory of a long run of --model")
    args = parser.parse_args()
    out: dict[str, Any] = {"load_before": [round(x, 2) for x in os.getloadavg()], "cpus": os.cpu_count()}
    out["seconds"], out["threads"] = args.seconds, args.threads
    audio = speech_like(args.seconds)
    ddim = [int(s) for s in args.ddim.split(",") if s]
    presets = [p for p in args.presets.split(",") if p]
    with tempfile.TemporaryDirectory(prefix="bench_a2p_") as tmp:
        folders: dict[str, Path] = {}
        for preset in presets:
            for precision in args.precisions.split(","):
                folders[f"{preset} {precision}"] = untrained_folder("a2p", preset, precision == "int8", Path(tmp))
        for model in args.model:
            folders[f"trained {model}"] = model
        table: dict[str, dict[str, float]] = {}
        for label, folder in folders.items():
            table[label] = {
                "default": rtf(folder, audio, args.threads),
                "distilled": rtf(folder, audio, args.threads, sampler="distilled"),
                "dpm": rtf(folder, audio, args.threads, sampler="dpm"),
            }
            for steps in ddim:  # guidance on face and body, every condition dropped, as the reference samples
                table[label][f"ddim{steps}"] = rtf(
                    folder,
                    audio,
                    args.threads,
                    sampler="ddim",
                    steps=steps,
                    face_steps=steps,
                    guidance_body=2.0,
                    guidance_body_on="all",
                )
            print(json.dumps({label: table[label]}), flush=True)
        out["rtf"] = table
        out["guide_80_tokens_s"] = {
            preset: {
                **guide_torch(preset),
                "onnx_kv_cache": guide_onnx(folders[f"{preset} fp32"], args.threads),
            }
            for preset in presets
            if f"{preset} fp32" in folders
        }
        live_audio = speech_like(20.0, seed=1)
        out["live"] = {
            label: {
                "default": live_latency(folder, live_audio, 1),
                "distilled": live_latency(folder, live_audio, 1, sampler="distilled"),
                "dpm": live_latency(folder, live_audio, 1, sampler="dpm"),
            }
            for label, folder in folders.items()
        }
    if args.model and args.long_minutes > 0:
        out["long"] = long_run(args.model[0], args.long_minutes)
    out["load_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
