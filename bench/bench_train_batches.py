"""Benchmark of what a training step waits for: assembling its batch from the corpus.

Prints JSON with
- ``batch_ms``: milliseconds to assemble one batch of each stage's windows (a2p and probtalk,
  ``--preset``), in this process: the time a GPU step waits when no worker assembles it ahead;
  ``augmented_ms``: the same with every augmentation kind at its default chance (``audio.augment``);
- ``steps_per_second``: a2p's ``lip`` stage trained ``--steps`` steps with ``--workers`` 0 and N
  on ``--device`` (the weights of both runs must agree exactly: ``same_weights``);
- the machine's load average before and after (the machine may be shared: quote it).

Usage: .venv/bin/python -m bench.bench_train_batches --corpus DIR [--preset small] [--steps 60] [--workers 6] [--device auto]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True, help="a corpus (convodrive corpus make)")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--steps", type=int, default=60, help="training steps to time per worker count")
    parser.add_argument("--workers", type=int, default=6, help="worker processes of the second run")
    parser.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    parser.add_argument("--repeats", type=int, default=5, help="batches timed per stage")
    args = parser.parse_args()

    import torch
    from safetensors.torch import load_file

    from bench.machine import cpu_name
    from convodrive.audio.augment import KINDS, Augment
    from convodrive.training.loop import TrainRequest, train
    from convodrive.training.registry import get_preset, get_recipe

    out: dict[str, object] = {
        "cpu": cpu_name(),
        "cpus": os.cpu_count(),
        "load_before": [round(x, 2) for x in os.getloadavg()],
    }
    batch_ms: dict[str, float] = {}
    augmented_ms: dict[str, float] = {}
    augment = Augment(KINDS)
    for model in ("a2p", "probtalk"):
        recipe = get_recipe(model)
        _, preset = get_preset(recipe, args.preset)
        config = recipe.model_config(dict(preset.model))
        batch = recipe.train_config(dict(preset.train)).batch_size
        for stage in recipe.stages:
            windows = recipe.load_data(args.corpus, config, stage).train
            rng = np.random.default_rng(0)
            started = time.perf_counter()
            for _ in range(args.repeats):
                windows.batch(rng.integers(0, len(windows), batch))
            batch_ms[f"{model} {stage}"] = round((time.perf_counter() - started) / args.repeats * 1e3, 1)
            started = time.perf_counter()
            for step in range(args.repeats):
                windows.step_batch(rng.integers(0, len(windows), batch), step, 0, augment)
            augmented_ms[f"{model} {stage}"] = round((time.perf_counter() - started) / args.repeats * 1e3, 1)
    out["batch_ms"] = batch_ms
    out["augmented_ms"] = augmented_ms

    work = Path(tempfile.mkdtemp(prefix="bench_train_batches_"))
    rates, weights = {}, []
    for workers in (0, args.workers):
        result = train(
            TrainRequest(
                "a2p",
                args.corpus,
                preset=args.preset,
                stage="lip",
                steps=args.steps,
                out=work / f"workers{workers}",
                device=args.device,
                progress=False,
                workers=workers,
                settings={"val_every": 10**9},
            )
        )
        rates[str(workers)] = round(result.steps_per_second, 2)
        assert result.checkpoint is not None  # a finished run has saved its last step
        weights.append(load_file(str(result.checkpoint / "model.safetensors")))
    out["steps_per_second"] = {"stage": "a2p lip", "device": args.device, "by_workers": rates}
    out["same_weights"] = all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
    out["load_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
