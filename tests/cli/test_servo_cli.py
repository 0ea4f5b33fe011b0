"""``convodrive emulate`` and ``convodrive servo`` against emulated buses."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.backends.servo import BUS_LATENCY_MS
from tests.conftest import require

pytestmark = require("hardware")

import dynamixel_sdk as sdk  # noqa: E402
import yaml  # noqa: E402

from convodrive.backends.servo.dynamixel_emulator import DynamixelEmulator, start_emulated_head  # noqa: E402
from convodrive.backends.servo.feetech_emulator import FeetechEmulator, start_emulated_feetech  # noqa: E402
from convodrive.cli.main import main  # noqa: E402
from convodrive.cli.servo import calibrate, set_joint_limits  # noqa: E402
from convodrive.retargeting.profile import resolve_profile_path  # noqa: E402


def test_scan_lists_the_emulated_servos(capsys) -> None:  # type: ignore[no-untyped-def]
    with DynamixelEmulator([1, 2, 7, 30], "xl330") as emu:
        assert main(["servo", "scan", "--port", emu.port]) == 0
    out = capsys.readouterr().out.splitlines()
    rows = [line.split() for line in out[1:]]
    assert [(int(r[1]), r[2], int(r[3])) for r in rows] == [(i, "xl330-m288", 52) for i in (1, 2, 7, 30)]


def test_feetech_scan_pings_each_id(capsys) -> None:  # type: ignore[no-untyped-def]
    """A Feetech bus has no broadcast ping: the scan asks the ids one by one (here 0-12)."""
    with FeetechEmulator([1, 2, 7, 12], "sts3215") as emu:
        latency = str(BUS_LATENCY_MS)  # each absent id costs a timeout: 2 x latency
        args = ["servo", "scan", "--bus", "feetech", "--port", emu.port, "--ids", "0-12", "--latency-ms", latency]
        assert main(args) == 0
        packets = emu.counters["packets"]
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert [(int(r[1]), r[2], r[3]) for r in rows] == [(i, "sts3215", "3.10") for i in (1, 2, 7, 12)]
    assert packets >= 13 + 4, "every id asked, and each servo found asked its firmware"
    with FeetechEmulator([], "sts3215") as emu:
        assert main(["servo", "scan", "--bus", "feetech", "--port", emu.port, "--ids", "1-3"]) == 2
    assert "no servo answers" in capsys.readouterr().err


def test_feetech_monitor_once_shows_health(capsys, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("COLUMNS", "200")
    with start_emulated_feetech() as emu:
        emu.hardware_error(4, "overheating")
        emu.vanish(6)
        assert main(["servo", "monitor", "--bus", "feetech", "--port", emu.port, "--once", "--retries", "0"]) == 0
    out = capsys.readouterr().out
    lines = {line.split("│")[1].strip(): line for line in out.splitlines() if line.count("│") > 5}
    assert "overheating" in lines["jaw"] and "fault" in lines["jaw"]
    assert "lost" in lines["eye_tilt"] and "ok" in lines["neck_pan"]


def test_scan_and_monitor_user_errors(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    with DynamixelEmulator([], "xl330") as emu:
        assert main(["servo", "scan", "--port", emu.port]) == 2
        assert main(["servo", "monitor", "--port", emu.port, "--once"]) == 2
    assert main(["servo", "scan", "--port", str(tmp_path / "ttyUSB9")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "no servo answers" in err[0] and "no servo answers" in err[1]
    assert "no such port" in err[2]


def test_monitor_once_shows_health(capsys, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("COLUMNS", "200")
    with start_emulated_head() as emu:
        emu.hardware_error(4, "overheating")
        emu.vanish(6)
        assert main(["servo", "monitor", "--port", emu.port, "--once"]) == 0
    out = capsys.readouterr().out
    lines = {line.split("│")[1].strip(): line for line in out.splitlines() if line.count("│") > 5}
    assert "overheating" in lines["jaw"] and "fault" in lines["jaw"]
    assert "lost" in lines["eye_tilt"] and "ok" in lines["neck_pan"]


def test_calibrate_writes_ranges_back_and_keeps_the_rest(tmp_path: Path) -> None:
    source = resolve_profile_path("servo_head")
    profile = tmp_path / "head.yaml"
    shutil.copy(source, profile)
    before = profile.read_text()
    sweeps = {"neck_pan": (1300, 2800), "jaw": (1850, 2040)}
    with start_emulated_head() as emu:

        def user_moves(name: str) -> None:  # the person turning the horn, then pressing Enter
            servo = emu.servo({"neck_pan": 1, "jaw": 4}[name])
            lo, hi = sweeps[name]
            for tick in list(range(2048, hi, 150)) + [hi] + list(range(hi, lo, -300)) + [lo]:
                servo.move_by_hand(tick)
                time.sleep(0.15 if tick in (lo, hi) else 0.01)  # a person lingers at the end stops

        limits = calibrate(
            str(profile), {"port": emu.port}, joints=["neck_pan", "jaw"], done=user_moves, say=lambda text: None
        )
        torque = [emu.servo(i).torque for i in range(1, 8)]
    assert limits == sweeps and not any(torque)
    after = profile.read_text()
    data = yaml.safe_load(after)["backends"]["dynamixel"]["joints"]
    assert (data["neck_pan"]["min_tick"], data["neck_pan"]["max_tick"]) == sweeps["neck_pan"]
    assert (data["jaw"]["min_tick"], data["jaw"]["max_tick"]) == sweeps["jaw"]
    changed = [(a, b) for a, b in zip(before.splitlines(), after.splitlines()) if a != b]
    assert len(changed) == 2 and all("min_tick" in b for _, b in changed)
    assert before.count("#") == after.count("#")


def test_feetech_calibrate_writes_the_same_profile_format(tmp_path: Path) -> None:
    source = resolve_profile_path("servo_head")
    profile = tmp_path / "head.yaml"
    shutil.copy(source, profile)
    before = profile.read_text()
    sweeps = {"neck_tilt": (1500, 2600)}
    with start_emulated_feetech() as emu:

        def user_moves(name: str) -> None:
            servo = emu.servo(2)
            lo, hi = sweeps[name]
            for tick in list(range(2048, hi, 150)) + [hi] + list(range(hi, lo, -300)) + [lo]:
                servo.move_by_hand(tick)
                time.sleep(0.15 if tick in (lo, hi) else 0.01)

        limits = calibrate(
            str(profile),
            {"port": emu.port},
            joints=["neck_tilt"],
            done=user_moves,
            say=lambda text: None,
            bus="feetech",
        )
        torque = [emu.servo(i).torque for i in range(1, 8)]
    assert limits == sweeps and not any(torque)
    backends = yaml.safe_load(profile.read_text())["backends"]
    joint = backends["feetech"]["joints"]["neck_tilt"]
    assert (joint["min_tick"], joint["max_tick"]) == sweeps["neck_tilt"]
    assert backends["dynamixel"] == yaml.safe_load(before)["backends"]["dynamixel"], "the other bus is untouched"
    changed = [b for a, b in zip(before.splitlines(), profile.read_text().splitlines()) if a != b]
    assert len(changed) == 1 and "velocity: 2400" in changed[0]


def test_set_limits_in_block_style_yaml() -> None:
    text = (
        "backends:\n  dynamixel:\n    joints:\n      a:\n        id: 1\n        min_tick: 5  # old\n"
        "      b:\n        id: 2\n  maestro:\n    joints:\n      a: {channel: 0}\n"
    )
    out = set_joint_limits(text, "dynamixel", {"a": (10, 20), "b": (30, 40)}, Path("x.yaml"))
    data = yaml.safe_load(out)["backends"]
    assert data["dynamixel"]["joints"] == {
        "a": {"id": 1, "min_tick": 10, "max_tick": 20},
        "b": {"id": 2, "min_tick": 30, "max_tick": 40},
    }
    assert "# old" in out and data["maestro"]["joints"]["a"] == {"channel": 0}


def _as_background_job() -> None:
    """What a shell does to a job started with `&` (and what `nohup ... &` inherits): SIGINT ignored."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def test_emulate_command_serves_until_interrupted() -> None:
    """Defect 14: started in the background, the emulator ignored SIGINT and served forever."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "emulate", "dynamixel", "--ids", "1-2", "--model", "xm430"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_as_background_job,
    )
    try:
        port_path = proc.stdout.readline().strip()
        port = sdk.PortHandler(port_path)
        assert port.openPort()
        ph = sdk.PacketHandler(2.0)
        assert [ph.ping(port, i)[:2] for i in (1, 2)] == [(1020, sdk.COMM_SUCCESS)] * 2

        def torque(servo_id: int, value: int) -> None:  # retried: a loaded machine may miss the SDK's timeout
            assert any(ph.write1ByteTxRx(port, servo_id, 64, value)[0] == sdk.COMM_SUCCESS for _ in range(5))

        for value in (1, 0):  # what a backend does at open and at close
            torque(1, value), torque(2, value)
            time.sleep(0.3)
        torque(2, 1)
        port.closePort()
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
    log = [line.split(" s  ", 1)[1] for line in proc.stderr.read().splitlines()[1:]]
    assert log[0] == "torque on: servo 1-2" and log[-1] == "stopped; torque still on: servo 2", log
    seen: dict[int, list[str]] = {1: [], 2: []}  # a loaded machine may split a burst over two lines
    for line in log[:-1]:
        state, servos = line.removeprefix("torque ").split(": servo ")
        for part in servos.split(", "):
            lo, _, hi = part.partition("-")
            for servo_id in range(int(lo), int(hi or lo) + 1):
                seen[servo_id].append(state)
    assert seen == {1: ["on", "off"], 2: ["on", "off", "on"]}, log


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--fault", "overload:99"], "no servo 99 on the emulated bus (ids: 1, 2, 3, 4, 5, 6, 7)"),
        (["--ids", "1-2", "--fault", "vanish:5@1+1"], "no servo 5 on the emulated bus"),
        (["--fault", "overload:3@nan"], "times must be from 0 to 86400 seconds"),
        (["--fault", "drop:5"], "drop takes a rate from 0 to 1"),
        (["--link", "/nonexistent/folder/ttyHEAD"], "--link /nonexistent/folder/ttyHEAD: no such folder"),
        (["--baudrate", "fast"], "option 'baudrate' must be a whole number"),
    ],
)
def test_emulate_refuses_what_it_cannot_serve(capsys, args: list[str], needle: str) -> None:  # type: ignore[no-untyped-def]
    """Defect 14: an id not on the bus was accepted, then threw in a background thread; --link into
    a missing folder crashed."""
    assert main(["emulate", "dynamixel", *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == "", "no port is printed: nothing is served"
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err


def test_emulate_link_never_replaces_a_file(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    assert main(["emulate", "dynamixel", "--link", str(precious)]) == 2
    assert "a file is already there" in capsys.readouterr().err and precious.read_text() == "keep me"
    assert main(["emulate", "maestro", "--fault", "drop:0"]) == 2
    assert "drop takes a count" in capsys.readouterr().err


def test_servo_tools_take_the_backends_declared_options(capsys) -> None:  # type: ignore[no-untyped-def]
    """The tools' bus flags are the dynamixel backend's options: same names, ranges and help."""
    with pytest.raises(SystemExit) as info:
        main(["servo", "monitor", "--help"])
    assert info.value.code == 0
    help_text = " ".join(capsys.readouterr().out.split())
    assert "--latency-ms LATENCY_MS USB adapter latency timer" in help_text and "from 0 to 255" in help_text
    assert main(["servo", "monitor", "--latency-ms", "999", "--once"]) == 2
    assert "backend dynamixel: option 'latency_ms' must be between 0 and 255, got 999" in capsys.readouterr().err
    assert main(["servo", "monitor", "--baudrate", "fast", "--once"]) == 2
    assert "option 'baudrate' must be a whole number, got 'fast'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["servo", "monitor", "--rate", "1e9"])
    assert info.value.code == 2 and "expected a number from 0.2 to 30" in capsys.readouterr().err
