"""Benchmark the avatar renderer: offscreen frames per second and skinning time, printed as JSON.

    .venv/bin/python bench/bench_render.py [--resolution 512x512] [--camera upper] [--frames 150] [--antialias]

The target is >= 30 fps at 512x512 with the upper-body camera on 2 CPU cores (software GL).
Frames are a moving, talking, blinking pose so skinning, blendshapes and lids all do real work;
``fps`` covers everything a video frame needs except H.264 encoding (pose, upload, draw, read back,
backdrop composite). The machine may be shared, so the load average is printed, and
``cpu_ms_per_frame`` (CPU time of all this process's threads, llvmpipe's included) gives a figure
that other processes disturb less: on 2 cores, ``2000 / cpu_ms_per_frame`` bounds the fps.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from convodrive.backends.avatar.render_scene import AvatarRenderer, parse_resolution
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX


def talking_clip(frames: int) -> MotionClip:
    rng = np.random.default_rng(0)
    clip = MotionClip.neutral(frames)
    t = np.arange(frames) / 30.0
    clip.pose[:] = rng.normal(0, 0.05, clip.pose.shape)
    clip.pose[:, JOINT_INDEX["left_shoulder"], 2] = -1.2 + 0.3 * np.sin(2 * t)
    clip.pose[:, JOINT_INDEX["right_shoulder"], 2] = 1.2 + 0.3 * np.sin(2.3 * t)
    clip.pose[:, JOINT_INDEX["left_elbow"], 1] = -0.8 + 0.3 * np.sin(3 * t)
    clip.pose[:, JOINT_INDEX["right_elbow"], 1] = 0.8
    clip.face[:, BLENDSHAPE_INDEX["jawOpen"]] = 0.5 + 0.5 * np.sin(9 * t)
    clip.face[:, BLENDSHAPE_INDEX["mouthSmileLeft"]] = 0.5 + 0.5 * np.sin(t)
    clip.face[:, BLENDSHAPE_INDEX["eyeBlinkLeft"]] = clip.face[:, BLENDSHAPE_INDEX["eyeBlinkRight"]] = (t % 3) < 0.15
    return clip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="512x512")
    ap.add_argument("--camera", default="upper", choices=("full", "upper", "face"))
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--antialias", action="store_true")
    args = ap.parse_args()
    width, height = parse_resolution(args.resolution)
    t0 = time.perf_counter()
    renderer = AvatarRenderer(width, height, args.camera, antialias=args.antialias)
    setup_s = time.perf_counter() - t0
    clip = talking_clip(args.frames)
    for i in range(10):  # warm up: first uploads, shader compilation
        renderer.render(clip.frame(i))
    renderer.stats.update(frames=0, skin_s=0.0, gl_s=0.0)
    per_frame = []
    cpu0 = time.process_time()
    for i in range(args.frames):
        t = time.perf_counter()
        renderer.render(clip.frame(i))
        per_frame.append(time.perf_counter() - t)
    cpu_s = time.process_time() - cpu0  # all of this process's threads, llvmpipe's included
    skin = []
    for i in range(min(args.frames, 60)):
        t = time.perf_counter()
        renderer.poser.pose(clip.frame(i))
        skin.append(time.perf_counter() - t)
    from convodrive.backends.avatar.pyrender_gl import select_platform

    ms = np.array(per_frame) * 1000
    result = {
        "bench": "render",
        "resolution": [width, height],
        "camera": args.camera,
        "antialias": args.antialias,
        "gl_platform": select_platform(),
        "frames": args.frames,
        "fps": round(args.frames / float(np.sum(per_frame)), 2),
        "frame_ms_median": round(float(np.median(ms)), 2),
        "frame_ms_p95": round(float(np.percentile(ms, 95)), 2),
        "cpu_ms_per_frame": round(1000 * cpu_s / args.frames, 2),
        "skinning_ms_per_frame": round(1000 * float(np.median(skin)), 3),
        "gl_ms_per_frame": round(1000 * renderer.stats["gl_s"] / max(renderer.stats["frames"], 1), 2),
        "vertices": renderer.rig.num_vertices,
        "triangles": int(sum(len(s.faces) for s in renderer.rig.surfaces)),
        "setup_s": round(setup_s, 2),
        "target_fps": 30,
        "cpu_count": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "machine": platform.processor() or platform.machine(),
    }
    renderer.close()
    print(json.dumps(result))


if __name__ == "__main__":
    main()
