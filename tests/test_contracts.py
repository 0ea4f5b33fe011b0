"""The import contracts (.importlinter) hold, and they can fail: a runtime module importing torch breaks them."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")
pytestmark = pytest.mark.import_linter


def _layout(dest: Path) -> Path:
    subprocess.run([sys.executable, str(REPO / "scripts" / "installed_layout.py"), str(dest)], check=True)
    return dest


def _lint(layout: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(LINT_IMPORTS), "--config", str(REPO / ".importlinter"), "--no-cache"],
        cwd=layout,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_contracts_hold(tmp_path: Path) -> None:
    result = _lint(_layout(tmp_path / "layout"))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "broken" in result.stdout and " 0 broken" in result.stdout


def test_torch_in_a_generator_breaks_the_runtime_contract(tmp_path: Path) -> None:
    layout = _layout(tmp_path / "layout")
    probe = layout / "convodrive" / "generators" / "probe_torch.py"
    probe.write_text("import torch\n")
    result = _lint(layout)
    assert result.returncode != 0
    assert "torch" in result.stdout and "BROKEN" in result.stdout
    probe.unlink()
    shutil.rmtree(layout / "convodrive" / "generators" / "__pycache__", ignore_errors=True)
    assert _lint(layout).returncode == 0


def test_a_backend_importing_another_breaks_independence(tmp_path: Path) -> None:
    layout = _layout(tmp_path / "layout")
    record = layout / "convodrive" / "backends" / "record.py"
    text = record.read_text()
    record.unlink()  # a link back to the repository: replace it, never write through it
    record.write_text(text + "\nfrom convodrive.backends import render  # noqa\n")
    result = _lint(layout)
    assert result.returncode != 0 and "another backend" in result.stdout
