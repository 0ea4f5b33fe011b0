"""Scheduler benchmark: wall-clock 30 fps with three backends, one slow, under CPU load.

Prints JSON: frame-time jitter p50/p99/max (ms), drift over the run (frames), late frames, and
frames lost per backend. Targets: p99 jitter ≤ 2 ms, drift 0 frames, fast backends lose 0.

    .venv/bin/python -m bench.bench_scheduler --seconds 600
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from convodrive import FPS
from convodrive.backends.base import Session
from convodrive.scheduler import MonotonicClock, Route, Scheduler, build_report
from tests.doubles import CountingBackend, SlowBackend, neutral_frames


def _burn(stop_at: float) -> None:
    x = 0
    while time.time() < stop_at:
        x += 1


def run_bench(seconds: float, load: bool = True) -> dict[str, Any]:
    frames = int(round(seconds * FPS))
    load_before = os.getloadavg()
    backends = [
        CountingBackend({"name": "fast_a"}),
        CountingBackend({"name": "fast_b"}),
        SlowBackend({"name": "slow", "delay": 0.2}),
    ]
    with tempfile.TemporaryDirectory() as tmp:
        session = Session(out_dir=Path(tmp), offline=False, num_frames=frames)
        for b in backends:
            b.open(b.spec, session)
        loader = None
        if load:
            loader = multiprocessing.get_context("spawn").Process(
                target=_burn, args=(time.time() + seconds + 5,), daemon=True
            )
            loader.start()
        try:
            scheduler = Scheduler(
                neutral_frames(frames), [Route(b) for b in backends], clock=MonotonicClock(), expected_frames=frames
            )
            result = scheduler.run()
        finally:
            if loader is not None:
                loader.terminate()
                loader.join()
    report = build_report(result, {})
    lost = {b.name: frames - len(b.indices) for b in backends}
    return {
        "seconds": seconds,
        "fps": FPS,
        "frames": result.frames,
        "cpu_load_process": load,
        "cores": os.cpu_count(),
        "load_average_before_after": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "clock_priority": result.clock_priority,
        "jitter_ms": report["jitter_ms"],
        "drift_frames": report["drift_frames"],
        "late_frames": result.late_frames,
        "frames_lost": lost,
        "effective_fps": report["effective_fps"],
        "targets": {"jitter_p99_ms": 2.0, "drift_frames": 0, "fast_backends_lost": 0},
        "targets_met": bool(
            report["jitter_ms"]["p99"] <= 2.0
            and abs(report["drift_frames"]) < 0.5
            and lost["fast_a"] == 0
            and lost["fast_b"] == 0
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--no-load", action="store_true", help="skip the CPU-loading process")
    args = parser.parse_args()
    print(json.dumps(run_bench(args.seconds, load=not args.no_load), indent=2))


if __name__ == "__main__":
    main()
