"""Benchmark of the learned-motion foundation: corpus making, training, export parity, metrics.

Prints JSON with
- ``corpus_hours_per_minute``: ``convodrive corpus make`` throughput (skipped with ``--corpus``);
- ``train_steps_per_second``: the ``fgd`` recipe (preset ``--preset``) on that corpus, one process;
- ``onnx_parity``: the exported graphs' max abs error against torch at each parity size;
- ``int8_fgd``: the FGD figures of two methods with the float and the int8 embedder;
- ``metrics_seconds``: the ``eval compare`` suite's time per method on the test split (the
  methods' own generation time excluded), and the test split's hours;
- the machine's load average before and after (the machine may be shared: quote it).

Usage: .venv/bin/python bench/bench_neural.py [--corpus DIR] [--hours 0.2] [--steps 100] [--preset small]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "convodrive.cli.main", *args], capture_output=True, text=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, default=None, help="an existing corpus (else one is made)")
    parser.add_argument("--hours", type=float, default=0.2, help="hours of corpus to make when --corpus is not given")
    parser.add_argument("--steps", type=int, default=100, help="training steps to time")
    parser.add_argument("--preset", default="small", help="fgd preset to train")
    parser.add_argument("--samples", type=int, default=4, help="samples per conversation for the metric suite")
    args = parser.parse_args()
    load_before = os.getloadavg()
    out: dict[str, object] = {"load_before": [round(x, 2) for x in load_before], "cpus": os.cpu_count()}
    work = Path(tempfile.mkdtemp(prefix="bench_neural_"))
    corpus = args.corpus
    if corpus is None:
        corpus = work / "corpus"
        started = time.monotonic()
        made = _cli("corpus", "make", "--hours", str(args.hours), "--out", str(corpus), "--seed", "0")
        if made.returncode != 0:
            print(made.stderr, file=sys.stderr)
            return 1
        out["corpus_hours_per_minute"] = round(args.hours / ((time.monotonic() - started) / 60), 3)
    out["corpus"] = str(corpus)

    from convodrive.training.loop import TrainRequest, train

    result = train(
        TrainRequest(
            "fgd",
            corpus,
            preset=args.preset,
            steps=args.steps,
            out=work / "run",
            device="cpu",
            progress=False,
            settings={"val_every": 10**9, "checkpoint_every": 10**9},
        )
    )
    out["train_steps_per_second"] = round(result.steps_per_second, 2)
    out["train_preset"] = args.preset

    from convodrive.training.export import export_model

    exported = export_model(result.checkpoint or work / "run", work / "model")
    out["onnx_parity"] = exported.parity

    from convodrive.pipeline.compare import CompareRequest, compare

    cmp = compare(
        CompareRequest(
            corpus, ("ground-truth", "random", "knn"), work / "cmp", samples=args.samples, fgd_model=work / "model"
        )
    )
    meta = json.loads((work / "cmp" / "compare.json").read_text())
    out["metrics_seconds"] = {k: v for k, v in cmp.seconds.items() if k.endswith("(metrics)")}
    # What int8 (dynamic, MatMul only) costs the embedder, measured on FGD itself.
    quantised = export_model(result.checkpoint or work / "run", work / "model_int8", int8=True)
    out["int8_output_cost"] = quantised.int8
    q = compare(
        CompareRequest(
            corpus, ("ground-truth", "random"), work / "cmp_int8", samples=args.samples, fgd_model=work / "model_int8"
        )
    )
    out["int8_fgd"] = {
        m: {p: {"float": cmp.results[m][p], "int8": q.results[m][p]} for p in ("FGD holistic", "FGD body", "FGD face")}
        for m in ("ground-truth", "random")
    }
    out["test_split_hours"] = meta["hours"]
    out["load_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
