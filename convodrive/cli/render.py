"""``convodrive render``: film saved motion clips (.npz or .bvh) as an avatar preview video.

Several clips are laid side by side in a grid, as K takes of the same audio are. With ``--audio``
the video runs exactly as long as the audio (clips are held on their last frame or cut); without
it, as long as the longest clip.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from convodrive import FPS
from convodrive.motion.clip import MotionClip
from convodrive.plumbing.errors import InputFileError, UserError

MOTION_SUFFIXES = (".npz", ".bvh")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "render",
        help="render saved motion (.npz, .bvh) as an avatar video",
        description="Render motion clips as a mesh-avatar mp4 (H.264, 30 fps) with a PNG contact "
        "sheet; several clips are shown side by side.",
    )
    p.add_argument("motion", nargs="+", type=Path, metavar="MOTION", help="motion clip(s): convodrive .npz or BVH")
    p.add_argument("--audio", type=Path, metavar="WAV", help="audio to mux; sets the video's length")
    p.add_argument(
        "--camera", default="upper", choices=("full", "upper", "face"), help="camera preset (default: upper)"
    )
    p.add_argument("--resolution", default="512x512", metavar="WxH", help="size of each take (default: 512x512)")
    p.add_argument("--out", type=Path, metavar="FILE", help="output .mp4 (default: next to the first clip)")
    p.add_argument("--antialias", action="store_true", help="4x multisampling (slower on CPU)")
    p.set_defaults(func=run)


def load_motion(path: Path) -> MotionClip:
    """A clip from ``.npz`` (ours) or ``.bvh`` (joints mapped to the canonical skeleton by name)."""
    suffix = path.suffix.lower()
    if suffix not in MOTION_SUFFIXES:
        raise InputFileError(path, f"unsupported motion format '{path.suffix or '(none)'}' (expected .npz or .bvh)")
    if not path.is_file():
        raise InputFileError(path, "no such file")
    if suffix == ".npz":
        from convodrive.motion.npz import load_clip

        clip = load_clip(path)
    else:
        from convodrive.motion.bvh import read_bvh

        clip = read_bvh(path)
    if clip.num_frames == 0:
        raise InputFileError(path, "clip has no frames")
    return clip


def frame_indices(clip: MotionClip, num_frames: int, fps: float = FPS) -> np.ndarray:
    """The clip frame shown at each output frame: nearest earlier sample, held at the end."""
    return np.minimum(np.floor(np.arange(num_frames) / fps * clip.fps + 1e-6).astype(int), clip.num_frames - 1)


def run(args: argparse.Namespace) -> int:
    from convodrive.audio.source import probe_audio
    from convodrive.backends.base import Session
    from convodrive.backends.render import RenderBackend
    from convodrive.cli.progress import frame_progress
    from convodrive.motion.targets import TargetFrame, TargetSpec

    clips = [load_motion(p) for p in args.motion]
    out = args.out if args.out is not None else args.motion[0].with_suffix(".mp4")
    if out.suffix.lower() != ".mp4":
        raise UserError(f"--out {out}: the video must be an .mp4 file")
    if out.exists() and out.is_dir():
        raise UserError(f"--out {out}: is a folder; give a file name ending in .mp4")
    duration = None
    if args.audio is not None:
        duration = probe_audio(args.audio).duration
        num_frames = max(1, int(round(duration * FPS)))
    else:
        num_frames = max(int(np.ceil(c.duration * FPS - 1e-6)) for c in clips)
    backend = RenderBackend(
        {
            "camera": args.camera,
            "resolution": args.resolution,
            "filename": out.name,
            "contact_sheet": f"{out.stem}_contact.png",
            "antialias": args.antialias,
        }
    )
    session = Session(
        out_dir=out.parent if str(out.parent) else Path("."),
        audio_path=args.audio,
        duration=duration,
        num_frames=num_frames,
        fps=FPS,
        offline=True,
        num_samples=len(clips),
    )
    indices = [frame_indices(c, num_frames) for c in clips]
    backend.open(TargetSpec.empty(), session)
    try:
        with frame_progress("rendering") as progress:
            for i in range(num_frames):
                takes = tuple(clip.frame(int(idx[i])) for clip, idx in zip(clips, indices))
                for take in takes:
                    take.time = i / FPS
                backend.send(TargetFrame(index=i, time=i / FPS, values=np.zeros(0), takes=takes))
                if progress:
                    progress(i + 1, num_frames)
    except BaseException:
        backend.abort()
        backend.close()
        raise
    backend.close()
    report = backend.report()
    for path in backend.outputs():
        print(path)
    print(
        f"{report['frames']} frames, {report['resolution'][0]}x{report['resolution'][1]}, "
        f"{report['render_fps']} fps rendering ({report['gl_platform']})"
    )
    return 0
