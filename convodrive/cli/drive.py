"""``convodrive drive``: audio in, motion out to the named backends."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from convodrive.cli.options import backend_key_value, channel_map, int_in, key_value, name_list
from convodrive.cli.progress import frame_progress
from convodrive.pipeline import DEFAULT_GENERATOR, MAX_SAMPLES, DriveRequest, DriveResult, drive
from convodrive.plumbing.errors import UserError
from convodrive.plumbing.logs import FILE_ONLY

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "drive",
        help="turn a conversation recording into motion for one or more backends",
        description="Generate motion from AUDIO (channel 0 = self, 1 = partner; mono = silent partner) "
        "and send it at 30 fps to each backend.",
    )
    p.add_argument("audio", type=Path, metavar="AUDIO", help="WAV, FLAC or OGG file, any sample rate")
    p.add_argument("--generator", default=DEFAULT_GENERATOR, help=f"generator plugin (default: {DEFAULT_GENERATOR})")
    p.add_argument(
        "--backend",
        type=name_list,
        default=("record",),
        metavar="NAME[,NAME]",
        help="backend plugins, comma-separated (default: record)",
    )
    p.add_argument(
        "--config",
        metavar="FILE|NAME",
        help="robot profile or run preset: a YAML file, or a bundled profile's name (e.g. servo_head)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("convodrive-out"),
        metavar="DIR",
        help="output folder (default: ./convodrive-out)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed: the same seed gives the same motion (default: 0)")
    p.add_argument(
        "--samples",
        type=int_in(1, MAX_SAMPLES),
        default=1,
        metavar="K",
        help=f"generate K takes of the same audio (1 to {MAX_SAMPLES})",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--realtime",
        action="store_true",
        help="pace frames by the wall clock (the default when a backend is hardware or a live window)",
    )
    mode.add_argument(
        "--offline",
        action="store_true",
        help="simulated clock, as fast as possible (the default when every backend writes files)",
    )
    p.add_argument(
        "--channels",
        type=channel_map,
        metavar="SELF,OTHER",
        help="which file channels are self and partner (needed for files with more than 2 channels)",
    )
    p.add_argument(
        "--motion",
        type=Path,
        metavar="FILE",
        help="motion file for the replay generator (.npz, .bvh or Live Link .csv)",
    )
    p.add_argument(
        "-G",
        "--generator-option",
        type=key_value,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="generator option, e.g. -G expressiveness=1.5",
    )
    p.add_argument(
        "-B",
        "--backend-option",
        type=backend_key_value,
        action="append",
        default=[],
        metavar="BACKEND.KEY=VALUE",
        help="backend option, e.g. -B render.camera=face",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    gen_options = dict(args.generator_option)
    if args.motion is not None:
        if args.generator != "replay":
            raise UserError(f"--motion is for the replay generator (this run's generator is {args.generator})")
        gen_options["motion"] = str(args.motion)
    backend_options: dict[str, dict] = {}
    for backend, key, value in args.backend_option:
        backend_options.setdefault(backend, {})[key] = value
    request = DriveRequest(
        audio=args.audio,
        generator=args.generator,
        backends=args.backend,
        config=args.config,
        out_dir=args.out,
        seed=args.seed,
        samples=args.samples,
        realtime=True if args.realtime else (False if args.offline else None),
        channels=args.channels,
        generator_options=gen_options,
        backend_options=backend_options,
    )

    def started(realtime: bool) -> None:
        if realtime:
            sys.stderr.write("convodrive: running in real time at 30 fps (Ctrl-C stops)\n")
            sys.stderr.flush()

    with frame_progress("driving", enabled=request.realtime is not True) as progress:
        result = drive(request, on_frame=progress, on_start=started)
    print_result(result)
    return exit_code(result)


def print_result(result: DriveResult) -> None:
    from convodrive.scheduler.report import summarize

    summary = summarize(result.report)
    print(summary)
    for path in result.outputs:
        print(f"wrote {path}")
    print(f"run report: {result.report_path}")
    sys.stdout.flush()
    log.info("run summary (report: %s)\n%s", result.report_path, summary, extra=FILE_ONLY)


def exit_code(result: DriveResult) -> int:
    """2 when the input stopped the run part-way (said in one line on stderr), 130 when interrupted."""
    if result.report.get("input_error"):
        message = f"{result.report['input_error']}; the run stopped there"
        sys.stderr.write(f"convodrive: error: {message}\n")
        log.error("%s", message, extra=FILE_ONLY)
        return 2
    return 130 if result.report["interrupted"] else 0
