"""``convodrive drive``: audio in, motion out to the named backends."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from convodrive.audio.source import READABLE
from convodrive.cli.options import add_motion_options, channel_map, int_in, plugin_options
from convodrive.cli.progress import drain_progress, frame_progress
from convodrive.pipeline import MAX_SAMPLES, DriveRequest, DriveResult, drive
from convodrive.plumbing.logs import FILE_ONLY

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "drive",
        help="turn a conversation recording into motion for one or more backends",
        description="Generate motion from AUDIO (channel 0 = self, 1 = partner; mono = silent partner) "
        "and send it at 30 fps to each backend.",
    )
    p.add_argument("audio", type=Path, metavar="AUDIO", help=f"{READABLE} file, any sample rate")
    add_motion_options(p)
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    gen_options, backend_options = plugin_options(args)
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
        result = drive(request, on_frame=progress, on_start=started, on_drain=drain_progress(progress, "drive"))
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


EXIT_BACKEND_FAILED = 3


def exit_code(result: DriveResult) -> int:
    """The run's exit status, each non-zero one said in one line on stderr: 3 when a body failed
    (hardware: a servo head that never opened, failed, or whose torque-off went unconfirmed; or
    every backend of the run, so nothing was driven), 2 when the input stopped the run part-way;
    else the shell's 128 + N when signal N stopped it (130 for Ctrl-C, 143 for SIGTERM), else 0."""
    report = result.report
    code = 0
    if report.get("interrupted"):
        name = report.get("stop_signal") or "SIGINT"
        code = 128 + int(getattr(signal, name, signal.SIGINT))
    if report.get("input_error"):
        _say(f"error: {report['input_error']}; the run stopped there")
        code = 2
    failed = report.get("hardware_failed") or {}
    if failed:
        names = "; ".join(f"{name}: {reason}" for name, reason in failed.items())
        _say(f"hardware failed ({names}); exit code {EXIT_BACKEND_FAILED}")
        code = EXIT_BACKEND_FAILED
    elif report.get("every_backend_failed"):
        from convodrive.scheduler.report import backend_state

        names = "; ".join(f"{name}: {backend_state(entry)[1]}" for name, entry in report["backends"].items())
        _say(f"every backend failed ({names}); exit code {EXIT_BACKEND_FAILED}")
        code = EXIT_BACKEND_FAILED
    return code


def _say(message: str) -> None:
    sys.stderr.write(f"convodrive: {message}\n")
    sys.stderr.flush()
    log.error("%s", message, extra=FILE_ONLY)
