"""``convodrive render``: film saved motion clips as an avatar preview video.

An ordinary pipeline run: the ``replay`` generator plays the clips (take k plays clip k) into the
``render`` backend, so a clip animates exactly as ``drive --generator replay --backend render``
shows it. With ``--audio`` the video runs as long as the audio (longer clips are cut, shorter ones
hold their last frame, and both are warned about); without it, as long as the longest clip, in
silence. The run report goes beside the video as ``NAME_report.json``.

Its flags are the render backend's options (``RenderOptions``: ``--camera``, ``--resolution``,
``--labels``...), made from that one declaration; only the file names come from ``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from convodrive import FPS
from convodrive.backends.render import RenderOptions
from convodrive.cli.progress import frame_progress
from convodrive.motion.load import FORMATS
from convodrive.plugins.option_help import add_option_arguments, option_arguments
from convodrive.plugins.options import merge_options
from convodrive.plumbing.errors import UserError

NAMED_BY_OUT = ("filename", "contact_sheet")
"""The render options ``--out`` sets (the video and, beside it, ``NAME_contact.png``)."""
RENDER_FLAGS = tuple(f.name for f in dataclasses.fields(RenderOptions) if f.name not in NAMED_BY_OUT)
"""Every other render option is a flag of this command."""
PLUGIN = "backend render"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "render",
        help="render saved motion (.npz, .bvh, Live Link .csv) as an avatar video",
        description="Render motion clips as a mesh-avatar mp4 (H.264, 30 fps) with a PNG contact "
        "sheet; several clips are shown side by side.",
    )
    p.add_argument("motion", nargs="+", type=Path, metavar="MOTION", help=f"motion clip(s): {FORMATS}")
    p.add_argument("--audio", type=Path, metavar="WAV", help="audio to mux; sets the video's length")
    p.add_argument("--out", type=Path, metavar="FILE", help="output .mp4 (default: next to the first clip)")
    add_option_arguments(p, RenderOptions, RENDER_FLAGS, show_defaults=True)
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
    named = {"filename": out.name, "contact_sheet": f"{out.stem}_contact.png"}
    flags = option_arguments(args, RENDER_FLAGS)
    render_options = merge_options(RenderOptions, [("", flags), ("", named)], plugin=PLUGIN)  # before any work
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
        backend_options={"render": render_options.as_dict()},
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
