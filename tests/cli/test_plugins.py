"""Third-party plugins: a package kept in tests/plugin_pkg is installed, listed, and used."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.conftest import run_cli


@pytest.mark.build_tools
def test_installed_plugin_is_listed(plugin_site: Path) -> None:
    out = run_cli("plugins", env={"PYTHONPATH": str(plugin_site)})
    assert out.returncode == 0, out.stderr
    assert "tiny_nod" in out.stdout and "nods the head once a second" in out.stdout
    assert "tiny_log" in out.stdout
    assert "record" in out.stdout


def test_plugin_is_not_listed_when_not_installed() -> None:
    out = run_cli("plugins")
    assert out.returncode == 0 and "tiny_nod" not in out.stdout


@pytest.mark.build_tools
def test_installed_plugins_drive_a_run(plugin_site: Path, tone_dialogue: Path, tmp_path: Path) -> None:
    out = run_cli(
        "drive",
        str(tone_dialogue),
        "--generator",
        "tiny_nod",
        "--backend",
        "tiny_log",
        "--out",
        str(tmp_path / "run"),
        env={"PYTHONPATH": str(plugin_site)},
    )
    assert out.returncode == 0, out.stderr
    pitches = json.loads((tmp_path / "run" / "tiny_log.json").read_text())
    assert len(pitches) == 90  # 3 s at 30 fps
    assert max(pitches) == pytest.approx(0.2, abs=0.01) and min(pitches) == pytest.approx(-0.2, abs=0.01)
    report = json.loads((tmp_path / "run" / "run_report.json").read_text())
    assert report["generator"]["name"] == "tiny_nod"
    assert report["backends"]["tiny_log"]["frames_sent"] == 90


@pytest.mark.build_tools
def test_plugin_with_a_missing_dependency_is_named_not_crashed(
    plugin_site: Path, tone_dialogue: Path, tmp_path: Path
) -> None:
    listing = run_cli("plugins", env={"PYTHONPATH": str(plugin_site)})
    line = next(ln for ln in listing.stdout.splitlines() if "tiny_missing" in ln)
    assert "unavailable" in line and "convodrive_no_such_module" in line
    out = run_cli(
        "drive",
        str(tone_dialogue),
        "--backend",
        "tiny_missing",
        "--out",
        str(tmp_path / "run"),
        env={"PYTHONPATH": str(plugin_site)},
    )
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    assert "convodrive_no_such_module" in out.stderr and "convodrive[imaginary]" in out.stderr


@pytest.mark.build_tools
def test_a_third_party_plugin_declares_options_the_same_way(
    plugin_site: Path, tone_dialogue: Path, tmp_path: Path
) -> None:
    env = {"PYTHONPATH": str(plugin_site)}
    listing = run_cli("plugins", "tiny_nod", env=env)
    assert listing.returncode == 0, listing.stderr
    assert "amplitude" in listing.stdout and "float, from 0 to 0.5; default 0.2" in listing.stdout
    out = run_cli(
        "drive", str(tone_dialogue), "--generator", "tiny_nod", "--backend", "tiny_log",
        "-G", "amplitude=0.1", "-B", "tiny_log.filename=pitch.json", "--out", str(tmp_path / "run"), env=env,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert max(json.loads((tmp_path / "run" / "pitch.json").read_text())) == pytest.approx(0.1, abs=0.01)
    typo = run_cli(
        "drive", str(tone_dialogue), "--generator", "tiny_nod", "--backend", "tiny_log",
        "-G", "amplitud=0.1", "--out", str(tmp_path / "bad"), env=env,
    )  # fmt: skip
    assert typo.returncode == 2
    assert typo.stderr.strip() == (
        "convodrive: error: generator tiny_nod: unknown option 'amplitud' (did you mean 'amplitude'?)"
    )
