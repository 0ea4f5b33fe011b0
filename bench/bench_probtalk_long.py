"""A long dialogue through probtalk in one stream: are the window seams continuous, is memory flat?

The audio is ``--audio`` (default: the bundled 25 s dialogue) repeated to ``--seconds`` and fed
as 100 ms chunks made on the fly, so nothing but the generator grows with the length. Prints JSON
with
- ``seams``: the largest frame-to-frame change at a window seam (a window's first new frame
  against the previous window's last) and inside windows, for the body (largest joint rotation
  change, degrees) and the face (largest blendshape change); a seam is continuous when its
  largest jump is no larger than the largest inside windows;
- ``rss_mib``: the process's resident memory after each minute of output; flat means constant
  memory (``growth_after_first_minute_mib``);
- the real-time factor and the machine's load average.

Usage: .venv/bin/python -m bench.bench_probtalk_long [--seconds 600] [--mode file] [--model DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.audio.source import ANALYSIS_RATE, CHUNK_SAMPLES, AudioChunk, AudioSource
from convodrive.generators.probtalk.generator import ProbTalkGenerator
from convodrive.motion.rotations import axis_angle_to_matrix

DIALOGUE = Path(__file__).resolve().parents[1] / "samples" / "dialogue.wav"


def looped_chunks(path: Path, seconds: float) -> Iterator[AudioChunk]:
    """``path``'s audio repeated to ``seconds``, 100 ms at a time (never held whole)."""
    audio = AudioSource(path).read_all()
    total, n = int(seconds * ANALYSIS_RATE), len(audio.self_voice)
    for start in range(0, total, CHUNK_SAMPLES):
        stop = min(start + CHUNK_SAMPLES, total)
        idx = np.arange(start, stop) % n
        yield AudioChunk(start, audio.self_voice[idx], audio.other_voice[idx], final=stop >= total)


def rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def rotation_change_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Largest angle, over joints, of the rotation taking pose ``a`` to pose ``b`` ((J, 3) axis-angle)."""
    ra, rb = axis_angle_to_matrix(a), axis_angle_to_matrix(b)
    cos = (np.einsum("jik,jik->j", ra, rb) - 1) / 2  # trace(ra^T rb) = 1 + 2 cos(angle)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--mode", default="file", choices=("file", "live"))
    parser.add_argument("--audio", type=Path, default=DIALOGUE)
    parser.add_argument("--model", default="", help="model folder (default: the shipped weights)")
    args = parser.parse_args()
    load_before = [round(x, 2) for x in os.getloadavg()]
    gen = ProbTalkGenerator({"model": args.model, "mode": args.mode, "threads": 1, "device": "cpu"})
    hop = gen.plan.hop
    # Allocated before the stream starts, so that the figures' own growth (a Python float a frame
    # in a list: 1.3 MiB over 10 minutes) does not show as the generator's.
    most = int(args.seconds * 30) + 2 * gen.plan.window
    body, face = np.full(most, np.nan), np.full(most, np.nan)  # written now: no pages touched later
    rss: list[float] = []
    previous = None
    started = time.perf_counter()
    frames = 0
    for frame in gen.stream(looped_chunks(args.audio, args.seconds), seed=0):
        if previous is not None:
            body[frames - 1] = rotation_change_deg(previous.pose, frame.pose)
            face[frames - 1] = np.abs(frame.face - previous.face).max()
        previous = frame
        frames += 1
        if frames % (60 * 30) == 0:
            rss.append(round(rss_mib(), 1))
    seconds = time.perf_counter() - started
    body, face = body[: max(frames - 1, 0)], face[: max(frames - 1, 0)]
    # change[i] is frame i+1 against frame i; window k >= 1 starts its new frames at k * hop.
    seam = np.zeros(len(body), bool)
    seam[np.arange(hop, len(body) + 1, hop) - 1] = True
    result: dict[str, Any] = {"frames": frames, "mode": args.mode, "window": gen.plan.window, "hop": hop}
    for name, change in (("body_deg", body), ("face", face)):
        result[name] = {
            "seams": int(seam.sum()),
            "largest_at_seams": round(float(change[seam].max()), 4),
            "largest_inside_windows": round(float(change[~seam].max()), 4),
            "p99_inside_windows": round(float(np.percentile(change[~seam], 99)), 4),
            "mean_at_seams": round(float(change[seam].mean()), 4),
            "mean_inside_windows": round(float(change[~seam].mean()), 4),
        }
        result[name]["continuous"] = result[name]["largest_at_seams"] <= result[name]["largest_inside_windows"]
    out = {
        "load_before": load_before,
        "model": gen.report()["model"],
        "seconds_of_audio": args.seconds,
        "real_time_factor": round(args.seconds / seconds, 1),
        "seams": result,
        "rss_mib": rss,
        "growth_after_first_minute_mib": round(rss[-1] - rss[0], 1) if rss else None,
        "load_after": [round(x, 2) for x in os.getloadavg()],
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
