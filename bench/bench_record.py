"""Benchmark of the recorder's memory: peak RSS of runs of growing length, which should stay flat.

Each case runs in a child process of its own and reports that process's peak resident memory
(``ru_maxrss`` from ``wait4``), its wall time and the size of what it wrote:

- ``record``: N minutes of 30 fps frames (two takes, a 7-joint robot's values) sent straight into
  the record backend, then its files written: the recorder alone.
- ``drive``: ``convodrive drive`` on a synthesised two-voice FLAC of N minutes with the default
  generator into the recorder: a whole run as a user makes it.

Prints JSON. Usage: .venv/bin/python -m bench.bench_record [--minutes 10 60 120] [--cases record drive]
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

REPO = Path(__file__).resolve().parents[1]


def record_child(minutes: float, out: Path) -> None:
    """Feed ``minutes`` of frames into the record backend (runs in the child)."""
    import numpy as np

    from convodrive.backends.base import Session
    from convodrive.backends.record import RecordBackend
    from convodrive.motion.clip import MotionFrame
    from convodrive.motion.targets import TargetFrame, TargetSpec

    joints = 7
    spec = TargetSpec(
        "head",
        tuple(f"j{i}" for i in range(joints)),
        -np.ones(joints),
        np.ones(joints),
        np.zeros(joints),
        np.full(joints, np.inf),
        np.full(joints, np.inf),
        ("rad",) * joints,
    )
    rng = np.random.default_rng(0)
    pool = []
    for _ in range(64):  # a pool of distinct frames, cycled: building frames is not what is measured
        m = MotionFrame.neutral()
        m.pose[:] = rng.normal(0, 0.3, m.pose.shape)
        m.face[:] = rng.uniform(0, 1, m.face.shape)
        pool.append(m)
    backend = RecordBackend()
    backend.open(spec, Session(out_dir=out, num_samples=2))
    values = rng.uniform(-1, 1, (64, joints)).astype(np.float32)
    for i in range(int(minutes * 60 * 30)):
        takes = (pool[i % 64], pool[(i + 7) % 64])
        backend.send(TargetFrame(index=i, time=i / 30, values=values[i % 64], takes=takes))
    backend.close()


def synthesised_dialogue(path: Path, minutes: float) -> None:
    """Two voices taking turns (voiced tone bursts with a syllable rhythm), written block by block."""
    import numpy as np
    import soundfile as sf

    sr = 16_000
    with sf.SoundFile(path, "w", samplerate=sr, channels=2, format="FLAC", subtype="PCM_16") as fh:
        for second in range(int(minutes * 60)):
            t = second + np.arange(sr) / sr
            syllables = 0.5 + 0.5 * np.sin(2 * np.pi * 4 * t)
            voice = 0.3 * np.sin(2 * np.pi * (140 + 30 * np.sin(2 * np.pi * 0.3 * t)) * t) * syllables
            turn = (second // 4) % 2
            fh.write(np.stack([voice * (turn == 0), voice * (turn == 1)], axis=1).astype(np.float32))


def measure(command: list[str], cwd: Path | None = None) -> dict:
    with tempfile.TemporaryFile("w+") as errors:
        start = time.perf_counter()
        proc = subprocess.Popen(command, cwd=cwd, stdout=subprocess.DEVNULL, stderr=errors, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        if status != 0:
            errors.seek(0)
            raise RuntimeError(f"{' '.join(command)} failed: {errors.read()[-2000:]}")
    return {"peak_rss_mb": round(usage.ru_maxrss / 1024, 1), "wall_s": round(wall, 1)}


def folder_mb(folder: Path) -> float:
    return round(sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 2**20, 1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[10, 60, 120])
    parser.add_argument("--cases", nargs="+", default=["record", "drive"], choices=["record", "drive"])
    parser.add_argument("--child", nargs=2, metavar=("MINUTES", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        record_child(float(args.child[0]), Path(args.child[1]))
        return 0
    result: dict = {"load_average": [round(x, 2) for x in os.getloadavg()], "cases": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for case in args.cases:
            rows = []
            for minutes in args.minutes:
                out = work / f"{case}-{minutes}"
                if case == "record":
                    figures = measure(
                        [sys.executable, "-m", "bench.bench_record", "--child", str(minutes), str(out)], REPO
                    )
                else:
                    audio = work / f"dialogue-{minutes}.flac"
                    synthesised_dialogue(audio, minutes)
                    command = [sys.executable, "-m", "convodrive.cli.main", "drive", str(audio), "--backend", "record"]
                    figures = measure(command + ["--out", str(out)])
                    audio.unlink()
                rows.append({"minutes": minutes, **figures, "outputs_mb": folder_mb(out)})
                subprocess.run(["rm", "-rf", str(out)], check=True)
            result["cases"][case] = rows
    result["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
