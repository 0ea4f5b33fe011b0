"""Benchmark of the corpus: how fast it is made, how fast training windows are read. Prints JSON.

- make: ``convodrive corpus make`` of ``--hours`` with ``--jobs`` workers into a temporary folder;
  minutes per corpus hour (the issue's target: one hour in at most 10 minutes on 2 cores), with
  the load average before and after (the machine may be shared).
- windows: random 180-frame windows (every array a training step reads) from the made corpus, or
  from ``--corpus DIR``; windows per second, cold (first touch of each page) and warm.

Usage: .venv/bin/python bench/bench_corpus.py [--hours 0.25] [--jobs N] [--corpus DIR] [--windows 2000]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from convodrive.corpus import Corpus
from convodrive.corpus.maker import default_jobs, make_corpus
from convodrive.generators.procedural import ProceduralGenerator


def read_windows(folder: Path, count: int, length: int = 180) -> dict:
    corpus = Corpus.open(folder)
    out = {}
    for label in ("first", "second"):
        rng = np.random.default_rng(0)
        start = time.perf_counter()
        windows = corpus.sample_windows("train", length, count, rng)
        for w in windows:
            w.features()
        out[f"windows_per_s_{label}_pass"] = round(count / (time.perf_counter() - start), 1)
    return {"window_frames": length, "windows": count, **out}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--hours", type=float, default=0.25)
    parser.add_argument("--jobs", type=int, default=default_jobs())
    parser.add_argument("--corpus", type=Path, help="read windows from this corpus instead of making one")
    parser.add_argument("--windows", type=int, default=2000)
    args = parser.parse_args()
    result: dict = {"cpus": os.cpu_count()}
    tmp = Path(tempfile.mkdtemp(prefix="bench-corpus-"))
    try:
        folder = args.corpus
        if folder is None:
            folder = tmp / "corpus"
            report = make_corpus(args.hours, folder, ProceduralGenerator, seed=0, jobs=args.jobs)
            result["make"] = report.to_json()
        result["read"] = read_windows(folder, args.windows)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    result["loadavg_end"] = [round(v, 2) for v in os.getloadavg()]
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
