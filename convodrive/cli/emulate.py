"""``convodrive emulate``: an emulated servo bus on a pseudo-terminal, for trying things without a robot.

It prints the port path on the first line (give it to ``--port`` or ``backends.<name>.port``) and
serves until Ctrl-C or SIGTERM, also when started in the background (where a shell would have it
ignore SIGINT). Faults can be scheduled: ``--fault vanish:3@5+2`` (servo 3 gone from 5 s to 7 s),
``--fault overload:4@10``, ``--fault drop:0.05``, ``--fault port@8+1``; a fault the bus cannot
have is refused before serving. On stderr it tells when torque (a Maestro: pulses) goes on or off,
and on which servos, and at the end which are still on.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from convodrive.backends.servo.servo_options import DynamixelOptions
from convodrive.plugins.options import check_options
from convodrive.plumbing.errors import UserError
from convodrive.plumbing.safe_yaml import parse_scalar


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "emulate",
        help="emulate a Dynamixel or Feetech bus, or a Pololu Maestro, on a pty",
        description="Serve an emulated servo bus on a pseudo-terminal; its path is "
        "printed on the first line. Runs until Ctrl-C.",
    )
    kinds = p.add_subparsers(dest="device", metavar="DEVICE", required=True)
    dxl = kinds.add_parser("dynamixel", help="Dynamixel Protocol 2.0 servos")
    dxl.add_argument("--ids", default="1-7", help="servo ids, e.g. 1-7 or 1,2,5-6 (default 1-7)")
    dxl.add_argument("--model", default="xl330", help="servo model (xl330, xm430, xl320, ...)")
    dxl.add_argument("--baudrate", default="1000000", help="emulated wire speed in bits per second (reply timing)")
    dxl.add_argument("--link", help="also make this path a symlink to the pty (stable across --fault port)")
    dxl.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[:ARG][@T][+D]",
        help="drop:RATE, corrupt:RATE, short:RATE, overload:ID, overheating:ID, input_voltage:ID, vanish:ID, port",
    )
    dxl.set_defaults(func=run_dynamixel)
    fee = kinds.add_parser("feetech", help="Feetech STS/SCS servos (SCS protocol)")
    fee.add_argument("--ids", default="1-7", help="servo ids, e.g. 1-7 or 1,2,5-6 (default 1-7)")
    fee.add_argument("--model", default="sts3215", help="servo model (sts3215, sts3250, scs0009, ...)")
    fee.add_argument("--baudrate", default="1000000", help="emulated wire speed in bits per second (reply timing)")
    fee.add_argument("--link", help="also make this path a symlink to the pty (stable across --fault port)")
    fee.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[:ARG][@T][+D]",
        help="drop:RATE, corrupt:RATE, short:RATE, overload:ID, overheating:ID, input_voltage:ID, vanish:ID, port",
    )
    fee.set_defaults(func=run_feetech)
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


def ranges(numbers: Iterable[int]) -> str:
    """``1-4, 7``: sorted numbers with runs joined."""
    out: list[str] = []
    for n in sorted(numbers):
        if out and out[-1].split("-")[-1] == str(n - 1):
            out[-1] = f"{out[-1].split('-')[0]}-{n}"
        else:
            out.append(str(n))
    return ", ".join(out)


class StateLog:
    """Prints when torque goes on or off. The backend switches servos one write at a time, so
    changes within ``settle_s`` of each other with the same cause are one line."""

    def __init__(self, unit: str, state: str, settle_s: float = 0.05) -> None:
        self.unit, self.state, self.settle_s = unit, state, settle_s
        self.on: set[int] = set()
        self._start = time.monotonic()
        self._pending: dict[tuple[bool, str], set[int]] = {}
        self._lock = threading.Lock()
        self._timer: threading.Timer | None = None

    def __call__(self, unit: int, on: bool, why: str = "") -> None:
        with self._lock:
            (self.on.add if on else self.on.discard)(unit)
            self._pending.setdefault((on, why), set()).add(unit)
            if self._timer is None:
                self._timer = threading.Timer(self.settle_s, self.flush)
                self._timer.daemon = True
                self._timer.start()

    def flush(self) -> None:
        with self._lock:
            pending, self._pending, self._timer = self._pending, {}, None
        for (on, why), units in pending.items():
            cause = f" ({why})" if why and why != "commanded" else ""
            self._say(f"{self.state} {'on' if on else 'off'}: {self.unit} {ranges(units)}{cause}")

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self.flush()
        still = f"still on: {self.unit} {ranges(self.on)}" if self.on else f"off on every {self.unit}"
        self._say(f"stopped; {self.state} {still}")

    def _say(self, text: str) -> None:
        print(f"{time.monotonic() - self._start:8.2f} s  {text}", file=sys.stderr, flush=True)


def _serve(emulator: object, describe: str, log: StateLog) -> int:
    """Print the port, then serve until Ctrl-C or SIGTERM (closing the pty and any link)."""
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)  # a background job starts with SIGINT ignored
    print(emulator.port, flush=True)  # type: ignore[attr-defined]
    print(describe, file=sys.stderr, flush=True)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()  # type: ignore[attr-defined]
        log.close()
    return 0


def run_dynamixel(args: argparse.Namespace) -> int:
    from convodrive.backends.servo.dynamixel_emulator import DynamixelEmulator

    return _run_bus(args, DynamixelEmulator, DynamixelOptions)


def run_feetech(args: argparse.Namespace) -> int:
    from convodrive.backends.servo.feetech_emulator import FeetechEmulator
    from convodrive.backends.servo.feetech_options import FeetechOptions

    return _run_bus(args, FeetechEmulator, FeetechOptions)


def _run_bus(args: argparse.Namespace, emulator: Callable[..., Any], options: type) -> int:
    """A serial-bus head (Dynamixel or Feetech): its servos on a pty, faults checked before it starts."""
    from convodrive.backends.servo.emulator_faults import parse_fault

    ids = parse_ids(args.ids)
    faults = [parse_fault(f) for f in args.fault]
    baudrate = check_options(options, {"baudrate": parse_scalar(args.baudrate)}, plugin="--baudrate")
    log = StateLog("servo", "torque")
    emu = emulator(ids, args.model, baudrate=baudrate["baudrate"], link=args.link, on_torque=log)
    for fault in faults:
        emu.check_fault(fault)
    emu.start()
    for fault in faults:
        emu.schedule(fault)
    model = next(iter(emu.servos.values())).model.name
    return _serve(emu, f"emulating {len(ids)} {model} servo(s), ids {args.ids}; Ctrl-C to stop", log)


def run_maestro(args: argparse.Namespace) -> int:
    from convodrive.backends.servo import maestro_protocol as mp
    from convodrive.backends.servo.emulator_faults import split_fault
    from convodrive.backends.servo.maestro_emulator import MaestroEmulator

    log = StateLog("channel", "pulses")
    emu = MaestroEmulator(args.channels, link=args.link, on_pulses=log)
    actions: list[tuple[float, Callable[[], None]]] = []
    for text in args.fault:
        spec = split_fault(text)
        if spec.kind not in ("drop", "port", *mp.ERROR_BITS.values()):
            raise UserError(f"--fault {text!r}: use drop:COUNT, port or one of {', '.join(mp.ERROR_BITS.values())}")
        if spec.kind == "drop":
            count = 1.0 if spec.arg is None else spec.arg
            if not (count.is_integer() and 1 <= count <= 1_000_000):
                raise UserError(f"--fault {text!r}: drop takes a count of replies from 1 to 1000000")
            actions.append((spec.at, lambda n=int(count): emu.drop_replies(n)))
        elif spec.kind == "port":
            actions.append((spec.at, lambda d=spec.duration: emu.unplug(d)))
        else:
            actions.append((spec.at, lambda name=spec.kind: emu.raise_error(name)))
    emu.start()
    for at, action in actions:
        emu.after(at, action)
    return _serve(emu, f"emulating a {args.channels}-channel Maestro; Ctrl-C to stop", log)
