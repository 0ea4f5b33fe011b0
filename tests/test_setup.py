"""``scripts/setup.sh`` on a fresh virtual environment says what it does in its own few lines: no
setuptools banners (licence, editable install), no pip chatter, and pip's output when pip fails."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from tests.conftest import REPO

pytestmark = [
    pytest.mark.slow,
    # setup.sh installs every extra the demo needs and checks the system packages: the machine must
    # already have them, or the script would fetch them (CI has them: it ran setup.sh first).
    pytest.mark.mujoco,
    pytest.mark.gl,
    pytest.mark.ffmpeg,
    pytest.mark.hardware,
    pytest.mark.pocketsphinx,
    pytest.mark.espeak,
    pytest.mark.xvfb,
    pytest.mark.bvh_reader,
]


def _copy_of_the_project(dest: Path) -> Path:
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, capture_output=True, text=True)
    if files.returncode != 0:
        pytest.skip("not a git checkout")
    for name in files.stdout.splitlines():
        source = REPO / name
        if source.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest / name)
    return dest


def _venv_that_sees(python: str, venv: Path, site: Path, *flags: str) -> None:
    """A new venv made by ``python`` whose packages include those in ``site`` (a .pth file)."""
    subprocess.run([python, "-m", "venv", *flags, str(venv)], check=True)
    ours = next((venv / "lib").glob("python3*/site-packages"))
    (ours / "shared.pth").write_text(f"{site}\n")


def _fresh_venv(project: Path) -> None:
    """A new .venv that sees the packages this interpreter has (so that nothing is downloaded), the
    way each worktree's venv reuses the shared one; its pip and build tools are this interpreter's
    too (a venv's own bundled setuptools is too old to read the pyproject, and no index may update it)."""
    _venv_that_sees(sys.executable, project / ".venv", Path(sysconfig.get_paths()["purelib"]), "--without-pip")


def _shared_dev_tools(project: Path) -> None:
    """Reachy Mini's daemon venv and the glTF validator, as this checkout has them (a venv that sees
    its packages, a link): ``--dev`` then checks them and moves on, as on a second run, instead of
    fetching 400 MB again. What setup prints for its own .venv is under test, not pip's cache."""
    reachy = REPO / ".venv-reachy"
    theirs = next((reachy / "lib").glob("python3*/site-packages"), None) if reachy.is_dir() else None
    if theirs is not None:
        _venv_that_sees(str(reachy / "bin" / "python"), project / ".venv-reachy", theirs, "--without-pip")
    node_modules = REPO / "tools" / "node" / "node_modules"
    if node_modules.is_dir():
        (project / "tools" / "node").mkdir(parents=True, exist_ok=True)
        (project / "tools" / "node" / "node_modules").symlink_to(node_modules)


def _offline_env() -> dict[str, str]:
    """The environment setup.sh runs in here: pip asks no package index (a test sends nothing beyond
    loopback) and builds the editable install with the setuptools the venv already sees, where it
    would fetch one into an isolated build environment."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONWARNINGS", "VIRTUAL_ENV")}
    return {**env, "PIP_NO_INDEX": "1", "PIP_NO_BUILD_ISOLATION": "0"}


def test_a_fresh_setup_prints_only_its_own_lines(tmp_path: Path) -> None:
    project = _copy_of_the_project(tmp_path / "convodrive")
    _fresh_venv(project)
    _shared_dev_tools(project)
    out = subprocess.run(
        ["scripts/setup.sh", "--dev"], cwd=project, capture_output=True, text=True, timeout=600, env=_offline_env()
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.splitlines() == ["setup: installing Python packages into .venv", "setup: ready (.venv)"]
    assert out.stderr == "", out.stderr
    probe = subprocess.run(
        [str(project / ".venv/bin/python"), "-c", "import convodrive.backends.record, convodrive.retargeting"],
        capture_output=True,
        text=True,
    )
    assert probe.returncode == 0, probe.stderr


def test_a_failing_pip_is_shown_and_stops_setup(tmp_path: Path) -> None:
    project = _copy_of_the_project(tmp_path / "convodrive")
    _fresh_venv(project)
    pyproject = project / "pyproject.toml"
    pyproject.write_text(pyproject.read_text().replace('name = "convodrive"', 'name = "convodrive"\nbroken = [', 1))
    out = subprocess.run(
        ["scripts/setup.sh"], cwd=project, capture_output=True, text=True, timeout=600, env=_offline_env()
    )
    assert out.returncode == 1
    assert "setup: ready" not in out.stdout
    assert "setup: pip install failed (above)" in out.stderr and "TOMLDecodeError" in out.stderr
