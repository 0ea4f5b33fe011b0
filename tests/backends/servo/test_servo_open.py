"""A servo head that cannot open says so once, and says why; a servo missing at open is refused."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import require

pytestmark = require("hardware")

from convodrive.backends.base import Session  # noqa: E402
from convodrive.backends.dynamixel import DynamixelBackend  # noqa: E402
from convodrive.backends.maestro import MaestroBackend  # noqa: E402
from convodrive.backends.servo.dynamixel_emulator import start_emulated_head  # noqa: E402
from convodrive.plumbing.errors import UserError  # noqa: E402
from convodrive.retargeting import load_profile  # noqa: E402
from tests.backends.servo.test_servo_closing import _tone  # noqa: E402

PROFILE = load_profile("servo_head")
BACKENDS = {"dynamixel": DynamixelBackend, "maestro": MaestroBackend}


def _ports(tmp_path: Path) -> dict[str, str]:
    return {"/dev/null": "/dev/null", "folder": str(tmp_path), "missing": str(tmp_path / "ttyUSB9")}


@pytest.mark.parametrize("kind", sorted(BACKENDS))
@pytest.mark.parametrize("port", ["/dev/null", "folder", "missing"])
def test_a_port_that_cannot_open_is_one_error_and_no_torque_off_claim(
    kind: str, port: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Defect 12: closing a head whose port never opened logged ``torque_off_failed`` for every joint."""
    path = _ports(tmp_path)[port]
    backend = BACKENDS[kind]({**PROFILE.backend_options(kind), "port": path})
    with caplog.at_level(logging.INFO), pytest.raises(UserError) as info:
        backend.open(PROFILE.spec, Session(out_dir=tmp_path))
    backend.close()  # what the scheduler does on every exit path
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: cannot open serial port ("), message
    assert not [r.getMessage() for r in caplog.records if r.levelno >= logging.INFO]
    assert not any("torque_off_failed" in f for f in backend.report()["faults"])


def test_the_cli_prints_one_line_for_a_port_that_cannot_open(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "convodrive.cli.main", "drive", str(_tone(tmp_path / "t.wav", 1.0)),
         "--backend", "dynamixel", "--out", str(tmp_path / "o"), "-B", "dynamixel.port=/dev/null"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    assert "/dev/null: cannot open serial port (not a serial port)" in out.stderr
    assert "torque_off" not in out.stderr


def test_a_dynamixel_servo_missing_at_open_is_refused_by_id(tmp_path: Path) -> None:
    """Defect 16: a missing servo only became a fault event and the run went on without it; a
    Maestro refuses a missing channel at open, and so does this."""
    with start_emulated_head(ids=[1, 2, 3, 4, 5, 7]) as emu:  # servo 6 (eye_tilt) absent
        backend = DynamixelBackend({**PROFILE.backend_options("dynamixel"), "port": emu.port, "latency_ms": 40})
        with pytest.raises(UserError) as info:
            backend.open(PROFILE.spec, Session(out_dir=tmp_path))
        backend.close()
        torque = [emu.servo(i).torque for i in (1, 2, 3, 4, 5, 7)]
    message = str(info.value)
    assert message.startswith("backends.dynamixel.joints.eye_tilt.id: servo 6 does not answer on "), message
    assert emu.port in message and "\n" not in message
    assert not any(torque)  # refused before any servo was switched on
