"""``convodrive emulate``: an emulated servo bus on a pseudo-terminal, for trying things without a robot.

It prints the port path on the first line (give it to ``--port`` or ``backends.<name>.port``) and
serves until Ctrl-C. Faults can be scheduled: ``--fault vanish:3@5+2`` (servo 3 gone from 5 s to
7 s), ``--fault overload:4@10``, ``--fault drop:0.05``, ``--fault port@8+1``.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from convodrive.plumbing.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "emulate",
        help="emulate a Dynamixel bus or a Pololu Maestro on a pty",
        description="Serve an emulated servo bus on a pseudo-terminal; its path is "
        "printed on the first line. Runs until Ctrl-C.",
    )
    kinds = p.add_subparsers(dest="device", metavar="DEVICE", required=True)
    dxl = kinds.add_parser("dynamixel", help="Dynamixel Protocol 2.0 servos")
    dxl.add_argument("--ids", default="1-7", help="servo ids, e.g. 1-7 or 1,2,5-6 (default 1-7)")
    dxl.add_argument("--model", default="xl330", help="servo model (xl330, xm430, xl320, ...)")
    dxl.add_argument("--baudrate", type=int, default=1_000_000, help="emulated wire speed (reply timing)")
    dxl.add_argument("--link", help="also make this path a symlink to the pty (stable across --fault port)")
    dxl.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[:ARG][@T][+D]",
        help="drop:RATE, corrupt:RATE, overload:ID, overheating:ID, input_voltage:ID, vanish:ID, port",
    )
    dxl.set_defaults(func=run_dynamixel)
    mae = kinds.add_parser("maestro", help="Pololu Maestro servo controller")
    mae.add_argument("--channels", type=int, default=12, choices=(6, 12, 18, 24))
    mae.add_argument("--link", help="also make this path a symlink to the pty")
    mae.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[:ARG][@T][+D]",
        help="drop:COUNT, port, or a Maestro error bit name such as serial_overrun",
    )
    mae.set_defaults(func=run_maestro)


def parse_ids(text: str) -> list[int]:
    ids: list[int] = []
    try:
        for part in text.split(","):
            lo, _, hi = part.partition("-")
            ids.extend(range(int(lo), int(hi or lo) + 1))
    except ValueError:
        raise UserError(f"--ids {text!r}: expected numbers and ranges such as 1-7 or 1,3,5-6") from None
    if not ids or any(not 0 <= i <= 252 for i in ids):
        raise UserError(f"--ids {text!r}: servo ids are 0..252")
    return sorted(set(ids))


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _serve(emulator: object, describe: str) -> int:
    """Print the port, then serve until Ctrl-C or SIGTERM (closing the pty and any link)."""
    print(emulator.port, flush=True)  # type: ignore[attr-defined]
    print(describe, file=sys.stderr, flush=True)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()  # type: ignore[attr-defined]
    return 0


def run_dynamixel(args: argparse.Namespace) -> int:
    from convodrive.backends.servo.dynamixel_emulator import DynamixelEmulator, parse_fault

    ids = parse_ids(args.ids)
    faults = [parse_fault(f) for f in args.fault]
    emu = DynamixelEmulator(ids, args.model, baudrate=args.baudrate, link=args.link).start()
    for fault in faults:
        emu.schedule(fault)
    model = next(iter(emu.servos.values())).model.name
    return _serve(emu, f"emulating {len(ids)} {model} servo(s), ids {args.ids}; Ctrl-C to stop")


def run_maestro(args: argparse.Namespace) -> int:
    from convodrive.backends.servo import maestro_protocol as mp
    from convodrive.backends.servo.dynamixel_emulator import split_fault
    from convodrive.backends.servo.maestro_emulator import MaestroEmulator

    emu = MaestroEmulator(args.channels, link=args.link)
    actions = []
    for text in args.fault:
        spec = split_fault(text)
        if spec.kind not in ("drop", "port", *mp.ERROR_BITS.values()):
            raise UserError(f"--fault {text!r}: use drop:COUNT, port or one of {', '.join(mp.ERROR_BITS.values())}")
        if spec.kind == "drop":
            actions.append((spec.at, lambda n=int(spec.arg or 1): emu.drop_replies(n)))
        elif spec.kind == "port":
            actions.append((spec.at, lambda d=spec.duration: emu.unplug(d)))
        else:
            actions.append((spec.at, lambda name=spec.kind: emu.raise_error(name)))
    emu.start()
    for at, action in actions:
        emu.after(at, action)
    return _serve(emu, f"emulating a {args.channels}-channel Maestro; Ctrl-C to stop")
