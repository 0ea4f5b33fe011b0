"""``convodrive live``: a conversation as it happens: the partner on a microphone, the robot's voice
on a speaker, motion in time with both."""

from __future__ import annotations

import argparse
import sys

from convodrive.cli.drive import exit_code, print_result
from convodrive.cli.options import add_motion_options, plugin_options
from convodrive.pipeline import SessionRequest, live


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "live",
        help="drive a body from a live conversation (microphone in, the robot's own voice out)",
        description="Listen to the partner, play the robot's own voice, and send motion in time with "
        "both: frame k goes out when sample k/30 s of the voice leaves the speaker. Runs until the "
        "inputs end, --seconds pass, or Ctrl-C; then servos ease to neutral and the report is written.",
    )
    p.add_argument(
        "--partner",
        default="default",
        metavar="DEVICE|FILE|none",
        help="the partner: a capture device (name, part of a name, or index; default: the default "
        "input), or an audio file played in real time as if it were one",
    )
    p.add_argument(
        "--self",
        dest="self_voice",
        default="none",
        metavar="FILE|-|tcp://HOST:PORT|none",
        help="the robot's own voice: a file, raw PCM on stdin (-), or a socket an agent's speech "
        "synthesiser connects to and writes into (off loopback it first sends a token line: "
        "?token=T, or the one printed) (default: none)",
    )
    p.add_argument(
        "--play", default="default", metavar="DEVICE", help="where the self voice is played (default: default)"
    )
    p.add_argument(
        "--self-rate",
        type=int,
        default=16000,
        metavar="HZ",
        help="sample rate of raw PCM on stdin or the socket: signed 16-bit little-endian mono (default: 16000)",
    )
    p.add_argument(
        "--monitor",
        metavar="DEVICE",
        help="a capture of what the speaker plays (a sink's monitor, or a microphone beside the speaker): "
        "the report then gives the measured audio–motion offset",
    )
    p.add_argument("--seconds", type=float, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--play-latency",
        type=_latency,
        default=0.1,
        metavar="low|high|SECONDS",
        help="output latency asked of the audio device (default: 0.1 s); the clock allows for any "
        "latency, so a larger one costs no sync and rides out a busy CPU",
    )
    p.add_argument("--list-devices", action="store_true", help="print the audio devices and exit")
    add_motion_options(p)
    p.set_defaults(func=run)


def _latency(text: str) -> float | str:
    if text in ("low", "high"):
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected low, high or seconds, got {text!r}") from None
    if not 0 < value <= 2:
        raise argparse.ArgumentTypeError(f"expected seconds between 0 and 2, got {text!r}")
    return value


def run(args: argparse.Namespace) -> int:
    if args.list_devices:
        from convodrive.audio.live.devices import describe_devices

        print(describe_devices())
        return 0
    if args.self_rate < 8000 or args.self_rate > 192000:
        from convodrive.plumbing.errors import UserError

        raise UserError(f"--self-rate must be between 8000 and 192000 Hz, got {args.self_rate}")
    gen_options, backend_options = plugin_options(args)
    request = SessionRequest(
        partner=args.partner,
        voice=args.self_voice,
        speaker=args.play,
        monitor=args.monitor,
        self_rate=args.self_rate,
        seconds=args.seconds,
        play_latency=args.play_latency,
        generator=args.generator,
        backends=args.backend,
        config=args.config,
        out_dir=args.out,
        seed=args.seed,
        generator_options=gen_options,
        backend_options=backend_options,
    )

    def started() -> None:
        sys.stderr.write("convodrive: live at 30 fps (Ctrl-C stops)\n")
        sys.stderr.flush()

    result = live(request, on_start=started)
    print_result(result)
    return exit_code(result)
