"""``convodrive render``: film saved motion clips as an avatar preview video.

An ordinary pipeline run: the ``replay`` generator plays the clips (take k plays clip k) into the
``render`` backend, so a clip animates exactly as ``drive --generator replay --backend render``
shows it. With ``--audio`` the video runs as long as the audio (longer clips are cut, shorter ones
hold their last frame, and both are warned about); without it, as long as the longest clip, in
silence. The run report goes beside the video as ``NAME_report.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from convodrive import FPS
from convodrive.cli.progress import frame_progress
from convodrive.motion.load import FORMATS
from convodrive.plumbing.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "render",
        help="render saved motion (.npz, .bvh, Live Link .csv) as an avatar video",
        description="Render motion clips as a mesh-avatar mp4 (H.264, 30 fps) with a PNG contact "
        "sheet; several clips are shown side by side.",
    )
    p.add_argument("motion", nargs="+", type=Path, metavar="MOTION", help=f"motion clip(s): {FORMATS}")
    p.add_argument("--audio", type=Path, metavar="WAV", help="audio to mux; sets the video's length")
    p.add_argument(
        "--camera", default="upper", choices=("full", "upper", "face"), help="camera preset (default: upper)"
    )
    p.add_argument("--resolution", default="512x512", metavar="WxH", help="size of each take (default: 512x512)")
    p.add_argument("--out", type=Path, metavar="FILE", help="output .mp4 (default: next to the first clip)")
    p.add_argument("--antialias", action="store_true", help="4x multisampling (slower on CPU)")
    p.add_argument(
        "--avatar",
        type=Path,
        metavar="PATH",
        help="a .glb/.gltf/.vrm avatar (or a YAML name map) instead of the mannequin",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from convodrive.cli.drive import exit_code, print_result
    from convodrive.motion.load import load_motion
    from convodrive.motion.resample import frames_covering
    from convodrive.pipeline import MAX_SAMPLES, DriveRequest, drive

    if len(args.motion) > MAX_SAMPLES:
        raise UserError(f"render: at most {MAX_SAMPLES} clips side by side, got {len(args.motion)}")
    out: Path = args.out if args.out is not None else args.motion[0].with_suffix(".mp4")
    if out.suffix.lower() != ".mp4":
        raise UserError(f"--out {out}: the video must be an .mp4 file")
    if out.is_dir():
        raise UserError(f"--out {out}: is a folder; give a file name ending in .mp4")
    duration = None
    if args.audio is None:  # as long as the longest clip
        duration = max(frames_covering(load_motion(p)) for p in args.motion) / FPS
    out_dir = out.parent if str(out.parent) else Path(".")
    request = DriveRequest(
        audio=args.audio,
        duration=duration,
        generator="replay",
        generator_options={"motion": [str(p) for p in args.motion]},
        backends=("render",),
        backend_options={
            "render": {
                "camera": args.camera,
                "resolution": args.resolution,
                "filename": out.name,
                "contact_sheet": f"{out.stem}_contact.png",
                "antialias": args.antialias,
                "avatar": str(args.avatar) if args.avatar else "",
            }
        },
        samples=len(args.motion),
        realtime=False,
        out_dir=out_dir,
        out_label=f"--out {out}",
        report_name=f"{out.stem}_report",
    )
    with frame_progress("rendering") as progress:
        result = drive(request, on_frame=progress)
    print_result(result)
    render = result.report["backends"].get("render", {})
    if render.get("failed"):
        problem = render.get("open_error") or render.get("last_error") or render.get("close_error")
        sys.stderr.write(f"convodrive: error: render failed: {problem}\n")
        return 1
    return exit_code(result)
