"""Start-up: commands that need no audio, motion or models do not import the heavy libraries.

``import scipy.signal`` alone takes seconds on a loaded machine; ``--help`` and the plugin listing
must not wait for it (nor for MuJoCo, ONNX Runtime, torch, pyrender, matplotlib, PortAudio).
Each command runs in a fresh interpreter with ``PYTHONPROFILEIMPORTTIME``, which lists on stderr
every module the interpreter imported.
"""

from __future__ import annotations

import pytest

from tests.conftest import run_cli

HEAVY = ("scipy", "mujoco", "onnxruntime", "torch", "pyrender", "matplotlib", "sounddevice")


def imported_modules(*args: str) -> set[str]:
    out = run_cli(*args, env={"PYTHONPROFILEIMPORTTIME": "1"})
    assert out.returncode == 0, out.stderr[-2000:]
    names = {line.rsplit("|", 1)[1].strip() for line in out.stderr.splitlines() if line.startswith("import time:")}
    assert "convodrive.cli.options" in names  # the listing is real: it saw the subcommands load
    return names


def loaded(names: set[str], packages: tuple[str, ...]) -> list[str]:
    return sorted(n for n in names if n.split(".")[0] in packages or n in packages)


@pytest.mark.parametrize("args", [("--help",), ("drive", "--help"), ("plugins", "procedural")])
def test_help_imports_no_heavy_library(args: tuple[str, ...]) -> None:
    assert loaded(imported_modules(*args), HEAVY) == []


def test_plugin_listing_imports_no_heavy_library() -> None:
    """Listing loads every plugin class; none imports its heavy machinery before it runs."""
    names = imported_modules("plugins")
    assert "convodrive.generators.procedural.signals" in names  # the listing did load the plugins
    assert "convodrive.backends.avatar.rig" in names
    assert loaded(names, HEAVY) == []
