"""``convodrive servo``: Dynamixel bus tools: scan, calibrate, monitor.

``scan`` lists the servos on a port (id, model, firmware). ``calibrate`` switches torque off and
asks you to move each joint through its whole range; the range seen becomes the joint's
``min_tick``/``max_tick`` in the profile, written back atomically with the rest of the file (and
its comments) untouched; a bundled profile named without a path is written to ./NAME.yaml
instead. ``monitor`` shows a live health table (position, temperature, voltage, hardware errors,
lost replies) without switching torque on.

The bus settings are the ``dynamixel`` backend's own options (``DynamixelOptions``): read from the
profile's ``backends.dynamixel``, overridden by flags made from the same declaration, and the bus
is built by the backend's own ``make_bus``; nothing here repeats a name, a default or a range.
"""

from __future__ import annotations

import argparse
import re
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from convodrive.backends.servo.servo_options import DynamixelOptions
from convodrive.cli.options import number_in
from convodrive.plugins.option_help import add_option_arguments, describe_options, option_arguments
from convodrive.plugins.options import check_options, merge_options
from convodrive.plumbing.atomic import write_text_atomic
from convodrive.plumbing.errors import InputFileError, UserError
from convodrive.plumbing.safe_yaml import parse_scalar, parse_yaml

STANDARD_BAUDRATES = (57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 9_600)
BUS_OPTIONS = ("port", "baudrate", "retries", "latency_ms")
"""The backend's options that the tools take as flags (``--latency-ms``)."""
PLUGIN = "backend dynamixel"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "servo",
        help="Dynamixel tools: scan, calibrate, monitor",
        description="Find, calibrate and watch the Dynamixel servos of a head.",
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
        t.set_defaults(func=fn)
    tools.choices["calibrate"].add_argument("--joint", action="append", help="only these joints (repeatable)")
    tools.choices["calibrate"].add_argument("--output", help="write the calibrated profile here instead")
    tools.choices["monitor"].add_argument(
        "--rate", type=number_in(0.2, 30), default=5.0, help="refreshes per second (0.2 to 30; default 5)"
    )
    tools.choices["monitor"].add_argument("--once", action="store_true", help="print one table and exit")


# ----------------------------------------------------------------------------- scan
def scan(port: str, baudrates: list[int]) -> list[tuple[int, int, int, int]]:
    """(baudrate, id, model number, firmware) for every servo that answers a broadcast ping."""
    from convodrive.backends.servo.dynamixel_bus import DynamixelBus

    found = []
    for baud in baudrates:
        bus = DynamixelBus(port, [], baudrate=baud)
        bus.connect()
        try:
            found += [(baud, i, model, fw) for i, (model, fw) in sorted(bus.scan().items())]
        finally:
            bus.disconnect()
    return found


def run_scan(args: argparse.Namespace) -> int:
    from convodrive.backends.servo.dynamixel_table import model_name

    given = [
        check_options(DynamixelOptions, {"baudrate": parse_scalar(b)}, plugin="--baudrate")["baudrate"]
        for b in args.baudrate or []
    ]
    rates = list(STANDARD_BAUDRATES) if args.all_baudrates else (given or [1_000_000])
    found = scan(args.port, rates)
    if not found:
        raise UserError(f"{args.port}: no servo answers at {', '.join(map(str, rates))} baud")
    print(f"{'baud':>8}  {'id':>3}  {'model':<12} firmware")
    for baud, servo_id, number, firmware in found:
        print(f"{baud:>8}  {servo_id:>3}  {model_name(number):<12} {firmware}")
    return 0


# ----------------------------------------------------------------------------- profile access
def _profile(config: str, flags: dict[str, Any] | None = None) -> tuple[Path, DynamixelOptions]:
    """The profile's file and its Dynamixel options, with the tools' flags on top."""
    from convodrive.retargeting.profile import load_profile

    profile = load_profile(config)
    path = Path(profile.path)
    options = merge_options(
        DynamixelOptions, [(str(path), profile.backend_options("dynamixel")), ("", flags)], plugin=PLUGIN
    )
    if not options.joints:
        raise InputFileError(path, "backends.dynamixel.joints: no servos configured")
    return path, options


def _bus(options: DynamixelOptions, names: list[str] | None = None):  # type: ignore[no-untyped-def]
    from convodrive.backends.dynamixel import bus_motors, make_bus

    motors = bus_motors(options, names)
    bus = make_bus(options, motors)
    bus.connect()
    if not any(bus.ping(m.id) for m in motors):
        bus.disconnect()
        raise UserError(f"{bus.port_name}: no servo answers (ids {', '.join(str(m.id) for m in motors)})")
    return bus


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
) -> dict[str, tuple[int, int]]:
    """Record each joint's range with torque off and write min/max ticks into the profile.
    ``flags`` override the profile's bus options (``{"port": ...}``)."""
    path, options = _profile(config, flags)
    assert options.joints is not None
    names = joints or list(options.joints)
    unknown = sorted(set(names) - set(options.joints))
    if unknown:
        raise UserError(f"--joint: {', '.join(unknown)} not in backends.dynamixel.joints of {path}")
    wait = done or (lambda name: input())
    bus = _bus(options)
    limits: dict[str, tuple[int, int]] = {}
    try:
        for name in names:
            say(f"{name}: torque is off. Move it slowly through its whole range, then press Enter.")
            seen = record_range(bus, name, lambda n=name: wait(n))
            if seen is None or seen[1] - seen[0] < 10:
                say(f"{name}: no movement seen ({seen}); keeping the old limits")
                continue
            limits[name] = seen
            say(f"{name}: min_tick {seen[0]}, max_tick {seen[1]}")
    finally:
        for name in options.joints:
            bus.write("Torque_Enable", name, 0)
        bus.disconnect()
    if limits:
        bundled = path != Path(config).expanduser()  # a profile name from the package: never edit it in place
        target = Path(output) if output else (Path.cwd() / path.name if bundled else path)
        text = set_joint_limits(path.read_text(encoding="utf-8"), "dynamixel", limits, path)
        write_text_atomic(target, text)
        say(f"wrote {len(limits)} joint range(s) to {target}")
    return limits


_KEY = re.compile(r"^(\s*)([A-Za-z_][\w-]*)\s*:(.*)$")


def set_joint_limits(text: str, backend: str, limits: dict[str, tuple[int, int]], path: Path) -> str:
    """Rewrite ``min_tick``/``max_tick`` of ``backends.<backend>.joints.<name>`` in place.

    A line-level edit, so comments, order and formatting of the rest of the profile survive
    (a YAML round trip would drop them). The result is parsed back to check every value landed.
    """
    lines = text.splitlines(keepends=True)
    stack: list[tuple[int, str]] = []
    spans: dict[str, list[int]] = {}
    for i, line in enumerate(lines):
        m = _KEY.match(line)
        if not m or line.lstrip().startswith("#"):
            continue
        indent = len(m.group(1))
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, m.group(2)))
        keys = [k for _, k in stack]
        if keys[:3] == ["backends", backend, "joints"] and len(keys) >= 4:
            spans.setdefault(keys[3], []).append(i)
    for name, (lo, hi) in limits.items():
        if name not in spans:
            raise InputFileError(path, f"backends.{backend}.joints.{name}: not found")
        for key, value in (("min_tick", lo), ("max_tick", hi)):
            pattern = re.compile(rf"(\b{key}\s*:\s*)-?\d+")
            hit = [i for i in spans[name] if pattern.search(lines[i])]
            if hit:
                lines[hit[0]] = pattern.sub(rf"\g<1>{value}", lines[hit[0]], count=1)
            elif "}" in lines[spans[name][0]]:  # flow mapping on one line: add before the brace
                head = spans[name][0]
                brace = lines[head].rfind("}")
                lines[head] = f"{lines[head][:brace]}, {key}: {value}{lines[head][brace:]}"
            else:
                head = spans[name][0]
                indent = len(lines[head]) - len(lines[head].lstrip()) + 2
                lines.insert(head + 1, " " * indent + f"{key}: {value}\n")
                spans = {k: [j + (j > head) for j in v] for k, v in spans.items()}
    result = "".join(lines)
    parsed = parse_yaml(result, path)
    for name, (lo, hi) in limits.items():
        got = parsed["backends"][backend]["joints"][name]
        if (got.get("min_tick"), got.get("max_tick")) != (lo, hi):
            raise InputFileError(path, f"backends.{backend}.joints.{name}: could not update the limits in place")
    return result


def run_calibrate(args: argparse.Namespace) -> int:
    if not sys.stdin.isatty():
        print("note: stdin is not a terminal; each Enter is read from it", file=sys.stderr)
    calibrate(args.config, option_arguments(args, BUS_OPTIONS), args.joint, args.output)
    return 0


# ----------------------------------------------------------------------------- monitor
def health_table(bus: Any) -> Any:
    """A rich table of one health read (SYNC_READ plus hardware errors on alert)."""
    from rich.table import Table

    from convodrive.backends.dynamixel import HEALTH_REGISTERS

    data = bus.sync_read(HEALTH_REGISTERS)
    for name in bus.take_alerts():
        status = bus.read("Hardware_Error_Status", name)
        if status is not None:
            bus.note_hardware_error(name, status)
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
            f"{regs['Present_Input_Voltage'] / 10:.1f}" if regs else "-",
            ",".join(d["faults"]) or "-",
            str(d["timeouts"] + d["corrupt"]),
            "-" if d["last_seen_s"] is None else f"{d['last_seen_s']:.2f}",
        )
    return table


def run_monitor(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    _, options = _profile(args.config, option_arguments(args, BUS_OPTIONS))
    bus = _bus(options)
    console = Console()
    try:
        if args.once:
            console.print(health_table(bus))
            return 0
        with Live(health_table(bus), console=console, refresh_per_second=max(1.0, args.rate)) as live:
            while True:
                time.sleep(1.0 / args.rate)
                live.update(health_table(bus))
    except KeyboardInterrupt:
        return 0
    finally:
        bus.disconnect()
