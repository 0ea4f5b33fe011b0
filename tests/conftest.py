"""Shared fixtures (the CLI as a user runs it, short synthetic conversations) and the markers for
what a test needs beyond the core install.

A core-only install (``pip install -e . pytest pytest-timeout hypothesis``) runs its share of the
suite. A test that needs an extra or a system tool carries a marker named in ``NEEDS`` below (and
registered in pyproject.toml: mujoco, gymnasium, gl, ffmpeg, hardware, pocketsphinx, espeak, xvfb,
bvh_reader, gltf_reader, gltf_validator, import_linter, build_tools, onnxruntime, torch, matplotlib,
transformers, live, reachy, pulseaudio, chromium); where the machine lacks it the test is
skipped with the reason and what installs it. CI installs everything and sets
``CONVODRIVE_TESTS_NEED_ALL=1``, which turns such a skip into a failure.

Mark a test (``@pytest.mark.gl``) or a module (``pytestmark = [pytest.mark.gl, ...]``) and import
the optional module inside the test, so that collection works without it; a module that needs it
at the top says ``pytestmark = require("hardware")`` above those imports.
"""

from __future__ import annotations

import ctypes
import fcntl
import functools
import importlib.util
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

REPO = Path(__file__).resolve().parents[1]

NEEDS: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    # marker: (Python modules, programs on PATH, what installs them)
    "mujoco": (("mujoco", "mink", "imageio_ffmpeg"), (), "pip install 'convodrive[sim]'"),
    "gymnasium": (("gymnasium",), (), "pip install 'convodrive[sim]'"),
    "gl": (
        ("pyrender", "OpenGL", "trimesh", "PIL", "imageio_ffmpeg"),
        (),
        "scripts/setup.sh, or pip install 'convodrive[render]'",
    ),
    "ffmpeg": ((), ("ffmpeg", "ffprobe"), "apt install ffmpeg"),
    "hardware": (("dynamixel_sdk", "scservo_sdk", "serial"), (), "pip install 'convodrive[hardware]'"),
    "pocketsphinx": (("pocketsphinx",), (), "pip install 'convodrive[speech]'"),
    "espeak": ((), ("espeak-ng",), "apt install espeak-ng"),
    "pipecat": (("pipecat",), (), "pip install 'convodrive[pipecat]' (scripts/setup.sh --dev)"),
    "livekit": (("livekit.agents",), (), "pip install 'convodrive[livekit]' (scripts/setup.sh --dev)"),
    "xvfb": ((), ("Xvfb",), "apt install xvfb (scripts/setup.sh --dev)"),
    "bvh_reader": (("bvh",), (), "pip install 'convodrive[dev]'"),
    "gltf_reader": (("pygltflib",), (), "pip install 'convodrive[dev]'"),
    "gltf_validator": ((), ("node",), "scripts/setup.sh --dev (nodejs and the gltf-validator package in tools/node)"),
    "import_linter": (("importlinter",), (), "pip install 'convodrive[dev]'"),
    "build_tools": (("wheel",), (), "pip install -U setuptools wheel, as scripts/setup.sh does"),
    "onnxruntime": (("onnxruntime",), (), "pip install 'convodrive[neural]'"),
    "torch": (("torch", "onnx", "onnxscript", "safetensors"), (), "pip install 'convodrive[train]'"),
    "matplotlib": (("matplotlib",), (), "pip install 'convodrive[eval]'"),
    "transformers": (("transformers",), (), "pip install 'convodrive[frontend]'"),
    "live": (("sounddevice", "websockets", "pythonosc"), (), "pip install 'convodrive[live]'"),
    "reachy": (("websockets",), (), "pip install 'convodrive[reachy]'; the daemon: scripts/setup.sh --dev"),
    "reachy_sdk": (
        ("reachy_mini", "gi", "asgiref", "zeroconf"),
        (),
        "Reachy Mini's official client, installed without its pins: scripts/setup.sh --dev",
    ),
    "pulseaudio": (
        ("sounddevice",),
        ("pulseaudio", "pactl", "paplay"),
        "apt install pulseaudio pulseaudio-utils libportaudio2 libasound2-plugins (scripts/setup.sh --dev)",
    ),
    "chromium": ((), ("chromium",), "apt install chromium (scripts/setup.sh --dev)"),
}
NEED_ALL = os.environ.get("CONVODRIVE_TESTS_NEED_ALL") == "1"


@functools.cache
def missing(marker: str) -> tuple[str, ...]:
    """What the machine lacks of a marker's needs (empty when the test can run)."""
    modules, programs, _ = NEEDS[marker]
    absent = tuple(m for m in modules if importlib.util.find_spec(m) is None)
    return absent + tuple(p for p in programs if shutil.which(p) is None)


def require(marker: str) -> pytest.MarkDecorator:
    """For a module whose every test needs ``marker``: ``pytestmark = require("hardware")``, above
    the imports that need it. Without them the module is skipped with the reason (a collection
    error under ``CONVODRIVE_TESTS_NEED_ALL=1``); with them it returns the marker."""
    absent = missing(marker)
    if absent:
        reason = f"needs {', '.join(absent)} ({NEEDS[marker][2]})"
        if NEED_ALL:
            raise ImportError(f"{reason}, and CONVODRIVE_TESTS_NEED_ALL=1 says everything is installed")
        pytest.skip(reason, allow_module_level=True)
    return getattr(pytest.mark, marker)


def pytest_runtest_setup(item: pytest.Item) -> None:
    for marker in NEEDS:
        if item.get_closest_marker(marker) is None:
            continue
        absent = missing(marker)
        if absent:
            reason = f"needs {', '.join(absent)} ({NEEDS[marker][2]})"
            if NEED_ALL:
                pytest.fail(f"{reason}, and CONVODRIVE_TESTS_NEED_ALL=1 says everything is installed")
            pytest.skip(reason)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests marked ``slow`` (half a minute or more, mostly in real time) go first: the suite runs on
    two workers (pytest-xdist), and one started last would leave the other idle at the end. The
    order is otherwise kept, so each worker collects the same list."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def realtime_allowed() -> bool:
    """Whether this process may use SCHED_FIFO (root, CAP_SYS_NICE or an rtprio limit)."""
    import threading

    if not hasattr(os, "sched_setscheduler") or os.environ.get("CONVODRIVE_NO_RENICE"):
        return False
    ok: list[bool] = []

    def attempt() -> None:  # in a thread of its own, which ends with the policy it set
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            ok.append(True)
        except OSError:
            ok.append(False)

    t = threading.Thread(target=attempt)
    t.start()
    t.join()
    return ok[0]


needs_realtime = pytest.mark.skipif(not realtime_allowed(), reason="this process may not use real-time scheduling")


def run_cli(
    *args: str,
    env: dict[str, str] | None = None,
    timeout: float = 300,
    cwd: Path | None = None,
    as_user: bool = False,
) -> subprocess.CompletedProcess:
    """Run ``convodrive`` in a fresh interpreter, as a user's shell would. ``as_user``: without
    root's power to read any file, so a file that is not readable reads as a user meets it."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "convodrive.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=full_env,
        cwd=cwd,
        preexec_fn=_drop_read_override if as_user else None,
    )


def wait_for(condition: Callable[[], bool], what: str, timeout: float = 10.0) -> None:
    """Block until ``condition()`` holds, polling every 10 ms; fail the test naming ``what`` after
    ``timeout`` seconds (which only stops a broken test hanging)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"waited {timeout:.0f} s for {what}"
        time.sleep(0.01)


def cli_in_process(*args: str) -> subprocess.CompletedProcess:
    """``convodrive`` in this interpreter, for the many one-line mistakes a command refuses before it
    does anything: the same ``main``, exit status and streams as ``run_cli`` gives, without a fresh
    interpreter's two to five seconds of imports (torch) per case. A traceback comes out as this
    test's error. Anything that runs a command's work, or needs a clean process, uses ``run_cli``."""
    import contextlib
    import io

    from convodrive.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse's own refusals
            code = exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess(["convodrive", *args], code, out.getvalue(), err.getvalue())


def _drop_read_override() -> None:
    """Drop CAP_DAC_OVERRIDE and CAP_DAC_READ_SEARCH from the bounding set before exec (Linux), so
    that even root is refused a file with mode 000."""
    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for capability in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        if libc.prctl(24, capability, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


@pytest.fixture
def tone_dialogue(tmp_path: Path) -> Path:
    """A 3 s stereo WAV at 44.1 kHz: self voiced in the first half, the partner in the second."""
    sr = 44_100
    t = np.arange(int(3.0 * sr)) / sr
    voice = 0.3 * np.sin(2 * np.pi * 180 * t) * (0.6 + 0.4 * np.sin(2 * np.pi * 4 * t))
    left = np.where(t < 1.5, voice, 0.0)
    right = np.where(t >= 1.5, voice, 0.0)
    path = tmp_path / "tones.wav"
    sf.write(path, np.stack([left, right], axis=1).astype(np.float32), sr, subtype="PCM_16")
    return path


def built_once(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], object]) -> Path:
    """The folder ``name`` that ``build(folder)`` makes once per test run, shared by pytest-xdist's
    workers: the first to ask builds it under a lock while the others wait, so a tiny model that
    takes a minute to train and export is made once, not once a worker. ``build`` must make the
    same folder whichever worker runs it (fixed seeds, no worker-specific paths inside)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the run's base folder; each worker's own is below it
    shared = root / "shared"
    shared.mkdir(exist_ok=True)
    folder, done = shared / name, shared / f"{name}.done"
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, or the worker dies
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)  # a worker that died half-way left it
            folder.mkdir()
            build(folder)
            done.touch()
    return folder


@pytest.fixture(scope="session")
def plugin_site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tests/plugin_pkg installed into a folder of its own: put it on PYTHONPATH to use its plugins."""
    return built_once(tmp_path_factory, "site", _install_plugin_pkg)


def _install_plugin_pkg(target: Path) -> None:
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "--target",
            str(target),
            str(REPO / "tests" / "plugin_pkg"),
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert build.returncode == 0, build.stderr


@pytest.fixture(scope="session")
def tiny_corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six 4 s conversations, two takes each, two speaker styles (tests/corpora.py)."""
    from tests.corpora import write_tiny_corpus

    return built_once(tmp_path_factory, "corpus", lambda folder: write_tiny_corpus(folder / "tiny")) / "tiny"


@pytest.fixture(scope="session")
def tiny_fgd_run(tiny_corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``fgd`` recipe's tiny preset trained for 10 steps on ``tiny_corpus`` (in this process)."""
    from convodrive.training.loop import TrainRequest, train

    def build(folder: Path) -> None:
        train(
            TrainRequest("fgd", tiny_corpus, preset="tiny", steps=10, out=folder / "run", device="cpu", progress=False)
        )

    return built_once(tmp_path_factory, "tiny_fgd", build) / "run"


@pytest.fixture(scope="session")
def tiny_fgd_model(tiny_fgd_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``tiny_fgd_run`` exported to an ONNX model folder."""
    from convodrive.training.export import export_model

    return (
        built_once(tmp_path_factory, "tiny_fgd_model", lambda folder: export_model(tiny_fgd_run, folder / "model"))
        / "model"
    )


@pytest.fixture(scope="session")
def real_dialogue() -> object:
    """A ~20 s two-voice dialogue of real speakers held out of training (tests/real_voices.py),
    from Debian packages fetched at setup (scripts/setup.sh --dev) or now. Without them the test
    is skipped; under CONVODRIVE_TESTS_NEED_ALL=1 it fails."""
    from tests.real_voices import fetch, real_dialogue

    voices, why = fetch()
    if voices is None:
        message = f"needs the real-voice packages: {why} (scripts/real_voices.sh, run by scripts/setup.sh --dev)"
        if NEED_ALL:
            pytest.fail(message)
        pytest.skip(message)
    return real_dialogue(voices)
