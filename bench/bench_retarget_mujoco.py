"""Bench: retargeting throughput, physics speed versus real time, offscreen video frame rate.

Prints one JSON object. Targets (issue 4): retarget_clip >= 10,000 frames/s on the humanoid map;
streaming retargeting + physics >= 10x real time without rendering; video fps at 640x480 reported.

    .venv/bin/python bench/bench_retarget_mujoco.py [--seconds 10] [--video-frames 90]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from convodrive.backends.base import Session
from convodrive.backends.mujoco_sim import MujocoBackend
from convodrive.motion.clip import MotionClip
from convodrive.motion.targets import TargetFrame
from convodrive.retargeting import Retargeter, load_profile


def motion(n: int, seed: int = 0) -> MotionClip:
    """Smooth random motion on every joint and face channel (sums of slow sinusoids)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None, None] / 30.0
    freq, phase = rng.uniform(0.1, 1.5, (1, 55, 3)), rng.uniform(0, 2 * np.pi, (1, 55, 3))
    clip = MotionClip.neutral(n)
    clip.pose[:] = 0.3 * np.sin(2 * np.pi * freq * t + phase)
    clip.pose[:, 16, 2] -= 1.2  # arms down, as in conversation
    clip.pose[:, 17, 2] += 1.2
    clip.face[:] = 0.5 + 0.5 * np.sin(2 * np.pi * rng.uniform(0.2, 3, 52) * t[:, :, 0] + rng.uniform(0, 6, 52))
    return clip


def run_backend(profile, clip: MotionClip, retargeter: Retargeter, out: Path, **options) -> tuple[float, MujocoBackend]:
    backend = MujocoBackend({"model": str(profile.model_path), **options})
    backend.open(profile.spec, Session(out_dir=out, num_frames=len(clip.pose)))
    retargeter.reset()
    start = time.perf_counter()
    for i, frame in enumerate(clip.frames()):
        backend.send(TargetFrame(i, frame.time, retargeter(frame), (frame,)))
    backend.close()
    return time.perf_counter() - start, backend


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds for the physics bench")
    ap.add_argument("--video-frames", type=int, default=90)
    ap.add_argument("--profile", default="convo_humanoid")
    args = ap.parse_args()

    profile = load_profile(args.profile)
    retargeter = Retargeter(profile)
    big = motion(9000)
    retargeter.retarget_clip(motion(30))  # warm up
    clip_rates = []
    for _ in range(5):  # the machine is shared: report the best and the median of five
        t0 = time.perf_counter()
        retargeter.retarget_clip(big)
        clip_rates.append(len(big.pose) / (time.perf_counter() - t0))
    clip_fps = max(clip_rates)

    n = round(args.seconds * 30)
    clip = motion(n, seed=1)
    frames = list(clip.frames())
    t0 = time.perf_counter()
    for f in frames:
        retargeter(f)
    stream_fps = n / (time.perf_counter() - t0)

    with tempfile.TemporaryDirectory() as tmp:
        wall, physics = run_backend(profile, clip, retargeter, Path(tmp), video=False)
        vclip = motion(args.video_frames, seed=2)
        vwall, video = run_backend(profile, vclip, retargeter, Path(tmp), video=True)
        rep = video.report()

    result = {
        "profile": profile.name,
        "joints": len(profile.spec.names),
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "retarget_clip_frames_per_s": round(clip_fps),
        "retarget_clip_frames_per_s_median": round(float(np.median(clip_rates))),
        "retarget_stream_frames_per_s": round(stream_fps),
        "physics_plus_retarget_x_realtime": round(args.seconds / wall, 2),
        "physics_only_x_realtime": round(physics.report()["physics_x_realtime"], 2),
        "physics_neck_head_rms_deg": round(physics.report()["neck_head_rms_deg"], 4),
        "video_gl": rep["gl"],
        "video_size": f"{video.width}x{video.height}",
        "video_render_fps": round(rep["render_fps"], 2) if rep["render_fps"] else None,
        "video_end_to_end_fps": round(args.video_frames / vwall, 2),
        "video_error": rep["video_error"],
        "targets": {"retarget_clip_frames_per_s": 10000, "physics_plus_retarget_x_realtime": 10},
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
