"""``convodrive servo``: servo bus tools (Dynamixel or Feetech, ``--bus``): scan, calibrate, monitor.

``scan`` lists the servos on a port (id, model, firmware): a Dynamixel bus by one broadcast ping, a
Feetech bus (which has none) by pinging each id of ``--ids``. ``calibrate`` switches torque off and
asks you to move each joint through its whole range; the range seen becomes the joint's
``min_tick``/``max_tick`` in the profile, written back atomically with the rest of the file (and
its comments) untouched; a bundled profile named without a path is written to ./NAME.yaml
instead. ``monitor`` shows a live health table (position, temperature, voltage, hardware errors,
lost replies) without switching torque on.

The bus settings are the chosen backend's own options (``DynamixelOptions``, ``FeetechOptions``):
read from the profile's ``backends.<bus>``, overridden by flags made from the same declaration, and
the bus is built by the backend's own ``new_bus``; nothing here repeats a name, a default or a range.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from convodrive.backends.servo.feetech_options import FeetechOptions
from convodrive.backends.servo.servo_options import DynamixelOptions
from convodrive.cli.emulate import parse_ids
from convodrive.cli.options import number_in
from convodrive.cli.servo_profile import set_joint_limits
from convodrive.plugins.option_help import add_option_arguments, describe_options, option_arguments
from convodrive.plugins.options import check_options, merge_options, parse_options
from convodrive.plumbing.atomic import write_text_atomic
from convodrive.plumbing.errors import InputFileError, UserError
from convodrive.plumbing.safe_yaml import parse_scalar

STANDARD_BAUDRATES = (57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 9_600)
BUS_OPTIONS = ("port", "baudrate", "retries", "latency_ms")
"""The backend's options that the tools take as flags (``--latency-ms``)."""
BUSES: dict[str, type[DynamixelOptions] | type[FeetechOptions]] = {
    "dynamixel": DynamixelOptions,
    "feetech": FeetechOptions,
}
"""The buses the tools speak, each with its backend's options (declared without the SDKs)."""


def backend_class(bus: str) -> Any:
    """The bus's backend class (``motors_for``, ``new_bus``, ``HEALTH_REGISTERS``); imports its SDK."""
    if bus == "feetech":
        from convodrive.backends.feetech import FeetechBackend

        return FeetechBackend
    from convodrive.backends.dynamixel import DynamixelBackend

    return DynamixelBackend


def _add_bus_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bus", choices=sorted(BUSES), default="dynamixel", help="servo family on the port (default dynamixel)"
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "servo",
        help="Dynamixel and Feetech tools: scan, calibrate, monitor",
        description="Find, calibrate and watch the Dynamixel or Feetech servos of a head.",
    )
    tools = p.add_subparsers(dest="tool", metavar="TOOL", required=True)
    info = {i.name: i for i in describe_options(DynamixelOptions)}
    scan = tools.add_parser("scan", help="list servo ids, models and firmware on a port")
    scan.add_argument("--port", required=True, help=info["port"].help)
    scan.add_argument(
        "--baudrate",
        action="append",
        help=f"{info['baudrate'].help} to try (repeatable; {info['baudrate'].kind()}; default 1000000)",
    )
    scan.add_argument("--all-baudrates", action="store_true", help="try every standard baud rate")
    scan.add_argument("--ids", default="0-252", help="only these ids, e.g. 1-7 or 1,2,5-6 (default 0-252)")
    add_option_arguments(scan, DynamixelOptions, ("latency_ms",))
    _add_bus_argument(scan)
    scan.set_defaults(func=run_scan)
    for name, fn, text in (
        ("calibrate", run_calibrate, "record each joint's range into the profile"),
        ("monitor", run_monitor, "live health table"),
    ):
        t = tools.add_parser(name, help=text)
        t.add_argument(
            "--config", default="servo_head", help="robot profile: a YAML file or a bundled name (default servo_head)"
        )
        add_option_arguments(t, DynamixelOptions, BUS_OPTIONS)
        _add_bus_argument(t)
        t.set_defaults(func=fn)
    tools.choices["calibrate"].add_argument("--joint", action="append", help="only these joints (repeatable)")
    tools.choices["calibrate"].add_argument("--output", help="write the calibrated profile here instead")
    tools.choices["monitor"].add_argument(
        "--rate", type=number_in(0.2, 30), default=5.0, help="refreshes per second (0.2 to 30; default 5)"
    )
    tools.choices["monitor"].add_argument("--once", action="store_true", help="print one table and exit")


# ----------------------------------------------------------------------------- scan
def scan(
    port: str, baudrates: list[int], bus: str = "dynamixel", ids: list[int] | None = None, latency_ms: float = 16.0
) -> list[tuple[int, int, str, str]]:
    """(baudrate, id, model, firmware) for every servo among ``ids`` that answers."""
    from convodrive.backends.servo.dynamixel_table import model_name

    wanted = list(range(253)) if ids is None else ids
    retries = 0 if bus == "feetech" and len(wanted) > 32 else 2  # a probe of every id: one ping each
    found = []
    for baud in baudrates:
        link = backend_class(bus).Bus(port, [], baudrate=baud, latency_ms=latency_ms, retries=retries)
        link.connect()
        try:
            if bus == "feetech":  # no broadcast ping: each id is asked
                found += [(baud, i, model, fw) for i, (model, fw) in sorted(link.scan(wanted).items())]
            else:
                servos = sorted(link.scan().items())
                found += [(baud, i, model_name(n), str(fw)) for i, (n, fw) in servos if i in wanted]
        finally:
            link.disconnect()
    return found


def run_scan(args: argparse.Namespace) -> int:
    given = [
        check_options(BUSES[args.bus], {"baudrate": parse_scalar(b)}, plugin="--baudrate")["baudrate"]
        for b in args.baudrate or []
    ]
    flags = parse_options(BUSES[args.bus], option_arguments(args, ("latency_ms",)), plugin=f"backend {args.bus}")
    rates = list(STANDARD_BAUDRATES) if args.all_baudrates else (given or [1_000_000])
    ids = parse_ids(args.ids)
    found = scan(args.port, rates, args.bus, ids, flags.latency_ms)
    if not found:
        raise UserError(f"{args.port}: no servo answers at {', '.join(map(str, rates))} baud")
    print(f"{'baud':>8}  {'id':>3}  {'model':<12} firmware")
    for baud, servo_id, model, firmware in found:
        print(f"{baud:>8}  {servo_id:>3}  {model:<12} {firmware}")
    return 0


# ----------------------------------------------------------------------------- profile access
def _profile(config: str, flags: dict[str, Any] | None = None, bus: str = "dynamixel") -> tuple[Path, Any]:
    """The profile's file and its options for ``bus``, with the tools' flags on top."""
    from convodrive.retargeting.profile import load_profile

    profile = load_profile(config)
    path = Path(profile.path)
    options = merge_options(
        BUSES[bus], [(str(path), profile.backend_options(bus)), ("", flags)], plugin=f"backend {bus}"
    )
    if not options.joints:
        raise InputFileError(path, f"backends.{bus}.joints: no servos configured")
    return path, options


def _bus(options: Any, bus: str = "dynamixel") -> Any:
    """The bus of ``options.joints``, connected, with at least one servo answering."""
    backend = backend_class(bus)
    motors = backend.motors_for(options)
    link = backend.new_bus(options, motors)
    link.connect()
    if not any(link.ping(m.id) for m in motors):
        link.disconnect()
        raise UserError(f"{link.port_name}: no servo answers (ids {', '.join(str(m.id) for m in motors)})")
    return link


# ----------------------------------------------------------------------------- calibrate
def record_range(bus: Any, name: str, done: Callable[[], None], period: float = 0.02) -> tuple[int, int] | None:
    """Torque off, then track Present_Position until ``done`` returns (the user pressed Enter)."""
    bus.write("Torque_Enable", name, 0)
    finished = threading.Event()

    def wait() -> None:
        try:
            done()
        except EOFError:  # stdin closed: stop sampling rather than wait forever
            pass
        finally:
            finished.set()

    threading.Thread(target=wait, daemon=True).start()
    seen: list[int] = []
    while True:
        last_round = finished.is_set()
        value = bus.read("Present_Position", name)
        if value is not None:
            seen.append(value)
        if last_round:
            break
        time.sleep(period)
    return (min(seen), max(seen)) if seen else None


def calibrate(
    config: str,
    flags: dict[str, Any] | None = None,
    joints: list[str] | None = None,
    output: str | None = None,
    done: Callable[[str], None] | None = None,
    say: Callable[[str], None] = print,
    bus: str = "dynamixel",
) -> dict[str, tuple[int, int]]:
    """Record each joint's range with torque off and write min/max ticks into the profile's
    ``backends.<bus>`` (one format for both buses). ``flags`` override its bus options (``{"port": ...}``)."""
    path, options = _profile(config, flags, bus)
    assert options.joints is not None
    names = joints or list(options.joints)
    unknown = sorted(set(names) - set(options.joints))
    if unknown:
        raise UserError(f"--joint: {', '.join(unknown)} not in backends.{bus}.joints of {path}")
    wait = done or (lambda name: input())
    link = _bus(options, bus)
    limits: dict[str, tuple[int, int]] = {}
    try:
        for name in names:
            say(f"{name}: torque is off. Move it slowly through its whole range, then press Enter.")
            seen = record_range(link, name, lambda n=name: wait(n))
            if seen is None or seen[1] - seen[0] < 10:
                say(f"{name}: no movement seen ({seen}); keeping the old limits")
                continue
            limits[name] = seen
            say(f"{name}: min_tick {seen[0]}, max_tick {seen[1]}")
    finally:
        for name in options.joints:
            link.write("Torque_Enable", name, 0)
        link.disconnect()
    if limits:
        bundled = path != Path(config).expanduser()  # a profile name from the package: never edit it in place
        target = Path(output) if output else (Path.cwd() / path.name if bundled else path)
        text = set_joint_limits(path.read_text(encoding="utf-8"), bus, limits, path)
        write_text_atomic(target, text)
        say(f"wrote {len(limits)} joint range(s) to {target}")
    return limits


def run_calibrate(args: argparse.Namespace) -> int:
    if not sys.stdin.isatty():
        print("note: stdin is not a terminal; each Enter is read from it", file=sys.stderr)
    calibrate(args.config, option_arguments(args, BUS_OPTIONS), args.joint, args.output, bus=args.bus)
    return 0


# ----------------------------------------------------------------------------- monitor
def health_table(bus: Any, kind: str = "dynamixel") -> Any:
    """A rich table of one health read (the backend's health registers, and the servos' faults)."""
    from rich.table import Table

    backend = backend_class(kind)
    data = bus.sync_read(backend.HEALTH_REGISTERS)
    bus.take_new_faults()  # the faults land in each servo's health record
    table = Table(title=f"{bus.port_name} at {bus.baudrate} baud")
    for column in ("joint", "id", "status", "position", "temp °C", "volt", "errors", "bad replies", "seen s ago"):
        table.add_column(column, no_wrap=column == "joint")
    for name, h in bus.health.items():
        regs = data.get(name, {})
        d = h.as_dict()
        style = {"ok": "green", "fault": "red", "lost": "yellow"}[d["status"]]
        table.add_row(
            name,
            str(h.id),
            f"[{style}]{d['status']}[/]",
            str(regs.get("Present_Position", "-")),
            str(regs.get("Present_Temperature", "-")),
            f"{regs[backend.VOLTAGE_REGISTER] / 10:.1f}" if regs else "-",
            ",".join(d["faults"]) or "-",
            str(d["timeouts"] + d["corrupt"]),
            "-" if d["last_seen_s"] is None else f"{d['last_seen_s']:.2f}",
        )
    return table


def run_monitor(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    _, options = _profile(args.config, option_arguments(args, BUS_OPTIONS), args.bus)
    bus = _bus(options, args.bus)
    console = Console()
    try:
        if args.once:
            console.print(health_table(bus, args.bus))
            return 0
        with Live(health_table(bus, args.bus), console=console, refresh_per_second=max(1.0, args.rate)) as live:
            while True:
                time.sleep(1.0 / args.rate)
                live.update(health_table(bus, args.bus))
    except KeyboardInterrupt:
        return 0
    finally:
        bus.disconnect()
