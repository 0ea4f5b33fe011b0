"""Reachy Mini's real daemon (PyPI ``reachy-mini``) in its simulations, for the backend's tests.

The daemon runs from its own venv (``.venv-reachy``, made by ``scripts/setup.sh --dev``; or the
Python in ``CONVODRIVE_REACHY_PYTHON``) through ``scripts/reachy_daemon.py``, which stubs out its
mDNS announcements, on a free port of 127.0.0.1, with telemetry off (``DO_NOT_TRACK=1``) and its
files in a temporary HOME: nothing leaves the machine. Stopped with SIGINT by its own pid.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import subprocess
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import NEED_ALL
from tests.pulse import pulse  # noqa: F401 (the fixture, for test_reachy_live.py)

ROOT = Path(__file__).resolve().parents[3]
LAUNCHER = ROOT / "scripts" / "reachy_daemon.py"
COMMON_FLAGS = [
    "--headless",
    "--no-media",
    "--dataset-update-interval",
    "0",
    "--no-goto-sleep-on-stop",
]
"""Without --no-wake-up-on-start: the daemon wakes the robot before it answers (a sleeping head is
below the backend's limits)."""
START_TIMEOUT_S = 60.0


def daemon_python() -> Path | None:
    """The Python that has ``reachy_mini`` installed, or None."""
    given = os.environ.get("CONVODRIVE_REACHY_PYTHON")
    path = Path(given) if given else ROOT / ".venv-reachy" / "bin" / "python"
    return path if path.exists() else None


@dataclasses.dataclass
class Daemon:
    port: int
    process: subprocess.Popen[bytes]
    log: Path

    @property
    def host(self) -> str:
        return "127.0.0.1"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _status(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/daemon/status", timeout=1.0) as reply:
            return bool(reply.status == 200)
    except OSError:
        return False


def start_daemon(tmp: Path, mode: list[str]) -> Daemon:
    python = daemon_python()
    if python is None:
        reason = "needs Reachy Mini's daemon in .venv-reachy (scripts/setup.sh --dev)"
        if NEED_ALL:
            pytest.fail(f"{reason}, and CONVODRIVE_TESTS_NEED_ALL=1 says everything is installed")
        pytest.skip(reason)
    port = _free_port()
    home = tmp / "home"
    home.mkdir(parents=True, exist_ok=True)
    env = {
        **os.environ,
        "HOME": str(home),
        "DO_NOT_TRACK": "1",
        "REACHY_MINI_TELEMETRY": "0",
        "HF_HUB_DISABLE_TELEMETRY": "1",
        "HF_HUB_OFFLINE": "1",
    }
    log = tmp / "daemon.log"
    with log.open("wb") as out:
        process = subprocess.Popen(
            ["nice", "-n", "10", str(python), str(LAUNCHER), *mode, *COMMON_FLAGS, "--fastapi-port", str(port)],
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            cwd=home,
        )
    deadline = time.monotonic() + START_TIMEOUT_S
    while not _status(port):
        if process.poll() is not None or time.monotonic() > deadline:
            stop_daemon(Daemon(port, process, log))
            pytest.fail(f"Reachy Mini's daemon did not start:\n{log.read_text()[-3000:]}")
        time.sleep(0.2)
    return Daemon(port, process, log)


def stop_daemon(daemon: Daemon) -> None:
    if daemon.process.poll() is None:
        daemon.process.send_signal(signal.SIGINT)
        try:
            daemon.process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            daemon.process.kill()
            daemon.process.wait()


@pytest.fixture(scope="session")
def reachy_mockup(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Daemon]:
    """The daemon in ``--mockup-sim`` mode (pure kinematics, instant), for the whole session."""
    daemon = start_daemon(tmp_path_factory.mktemp("reachy_mockup"), ["--mockup-sim"])
    yield daemon
    stop_daemon(daemon)


@pytest.fixture
def reachy_mujoco(tmp_path: Path) -> Iterator[Daemon]:
    """The daemon in MuJoCo ``--sim --headless`` mode (PD actuators, physical reachability)."""
    daemon = start_daemon(tmp_path, ["--sim"])
    yield daemon
    stop_daemon(daemon)
