"""Plugin options as a user meets them on the command line and in YAML (issue 9, item 5 and
defects 2, 6, 10, 12, 19): every mistake is one line naming the file, the plugin, the key and the
problem, exit code 2, never a traceback, and nothing runs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from convodrive.cli.main import main
from convodrive.retargeting.profile import resolve_profile_path
from tests.conftest import run_cli


def one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str], *needles: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for needle in needles:
        assert needle in err[0], (needle, err[0])
    return err[0]


def drive(audio: Path, tmp_path: Path, *args: str) -> list[str]:
    return ["drive", str(audio), "--out", str(tmp_path / "out"), *args]


def config(tmp_path: Path, text: str, name: str = "run.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_samples_is_bounded(capsys, tone_dialogue: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Defect 2: --samples 99999999999 was accepted and the kernel killed the run at 24 GB."""
    with pytest.raises(SystemExit) as info:
        main(drive(tone_dialogue, tmp_path, "--samples", "99999999999"))
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "--samples" in err and "from 1 to 16" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "args, needles",
    [
        pytest.param(
            ["--backend", "mujoco", "-B", "mujoco.width=abc"],
            ["backend mujoco: option 'width' must be a whole number, got 'abc'"],
            marks=pytest.mark.mujoco,
        ),
        pytest.param(
            ["--backend", "mujoco", "-B", "mujoco.width=99999"],
            ["option 'width' must be between 16 and 4096"],
            marks=pytest.mark.mujoco,
        ),
        (["--backend", "record", "-B", "render.camera=face"], ["backend 'render' is not in this run", "record"]),
        (["-G", "expresiveness=2"], ["generator procedural: unknown option 'expresiveness'", "'expressiveness'"]),
        (["-G", "expressiveness=lots"], ["option 'expressiveness' must be a number, got 'lots'"]),
        (["-G", "vad_off_db=-10"], ["generator procedural: vad_off_db (-10) must not exceed vad_on_db (-40)"]),
        (["--motion", "x.npz"], ["--motion is for the replay generator"]),
        pytest.param(
            ["--backend", "dynamixel", "-B", "dynamixel.raed_rate=5"],
            ["unknown option 'raed_rate'", "'read_rate'"],
            marks=pytest.mark.hardware,
        ),
        pytest.param(
            ["--backend", "dynamixel", "-B", "dynamixel.watchdog_s=-1"],
            ["option 'watchdog_s' must be between 0.05"],
            marks=pytest.mark.hardware,
        ),
        (["--backend", "mujco"], ["unknown backend 'mujco' (did you mean 'mujoco'?)"]),
    ],
)
def test_command_line_option_mistakes(capsys, tone_dialogue: Path, tmp_path: Path, args, needles) -> None:  # type: ignore[no-untyped-def]
    one_line_error(capsys, drive(tone_dialogue, tmp_path, *args), *needles)
    assert not (tmp_path / "out").exists(), "nothing runs, nothing is left behind"


@pytest.mark.parametrize(
    "text, backend, needles",
    [
        pytest.param(
            "backends: {dynamixel: {watchdog_s: soon}}",
            "dynamixel",
            ["option 'watchdog_s' must be a number, got 'soon'"],
            marks=pytest.mark.hardware,
        ),
        pytest.param(
            "backends: {dynamixel: {watchdog_s: -1}}",
            "dynamixel",
            ["option 'watchdog_s' must be between 0.05 and 10"],
            marks=pytest.mark.hardware,
        ),
        pytest.param(
            "backends: {dynamixel: {raed_rate: 5}}",
            "dynamixel",
            ["unknown option 'raed_rate' (did you mean 'read_rate'?)"],
            marks=pytest.mark.hardware,
        ),
        ("backends: {record: 5}", "record", ["backend record: options must be a mapping of names to values, got 5"]),
        ("backends: {mujco: {width: 320}}", "record", ["backends: unknown backend 'mujco' (did you mean 'mujoco'?)"]),
        # a section for a backend the run does not use is still checked: the file is wrong
        pytest.param(
            "backends: {mujoco: {widht: 320}}",
            "record",
            ["backend mujoco: unknown option 'widht'", "'width'"],
            marks=pytest.mark.mujoco,
        ),
        ("generator: {procedural: {expressiveness: 9}}", "record", ["generator procedural: option 'expressiveness'"]),
        ("backends: [record]", "record", ["'backends' must be a mapping of names to options"]),
        ("generator: [unclosed\n", "record", ["not valid YAML at line 2: expected ',' or ']'"]),
        ("- just\n- a list\n", "record", ["a config must be a YAML mapping"]),
    ],
)
def test_config_file_mistakes_name_the_file(
    capsys, tone_dialogue: Path, tmp_path: Path, text, backend, needles
) -> None:  # type: ignore[no-untyped-def]
    path = config(tmp_path, text)
    line = one_line_error(capsys, drive(tone_dialogue, tmp_path, "--backend", backend, "--config", str(path)), *needles)
    assert line.startswith(f"convodrive: error: {path}"), line


@pytest.mark.hardware
@pytest.mark.mujoco
def test_a_profiles_backend_options_name_the_profile(capsys, tone_dialogue: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Defect 12: backend option errors did not name the file they came from."""
    profile = tmp_path / "my_head.yaml"
    text = resolve_profile_path("servo_head").read_text().replace("baudrate: 1000000", "baudrate: fast", 1)
    profile.write_text(text)
    one_line_error(
        capsys,
        drive(tone_dialogue, tmp_path, "--backend", "dynamixel", "--config", str(profile)),
        f"{profile}: backend dynamixel: option 'baudrate' must be a whole number, got 'fast'",
    )
    # the same profile named by a run config's backends.mujoco.profile is checked too
    run = config(tmp_path, f"backends: {{mujoco: {{profile: {profile}, video: false}}}}")
    one_line_error(
        capsys,
        drive(tone_dialogue, tmp_path, "--backend", "mujoco", "--config", str(run)),
        f"{profile}: backend dynamixel: option 'baudrate'",
    )


def test_unreadable_and_odd_config_files(capsys, tone_dialogue: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Defect 10: an unreadable config file gave a traceback."""
    folder = tmp_path / "folder.yaml"
    folder.mkdir()
    one_line_error(capsys, drive(tone_dialogue, tmp_path, "--config", str(folder)), str(folder), "is a folder")
    missing = tmp_path / "absent.yaml"
    one_line_error(
        capsys, drive(tone_dialogue, tmp_path, "--config", str(missing)), str(missing), "no such config file"
    )
    binary = config(tmp_path, "", "binary.yaml")
    binary.write_bytes(b"\xff\xfe\x00garbage")
    one_line_error(capsys, drive(tone_dialogue, tmp_path, "--config", str(binary)), "not UTF-8 text")
    locked = config(tmp_path, "generator: {procedural: {}}\n", "locked.yaml")
    locked.chmod(0)
    out = run_cli(*drive(tone_dialogue, tmp_path, "--config", str(locked)), as_user=True)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert out.stderr.strip() == f"convodrive: error: {locked}: cannot read (permission denied)"


def test_unreadable_audio_says_permission_denied(tmp_path: Path, tone_dialogue: Path) -> None:
    """Defect 12: libsndfile's "System error." told the user nothing."""
    locked = tmp_path / "locked.wav"
    shutil.copy(tone_dialogue, locked)
    locked.chmod(0)
    out = run_cli("drive", str(locked), "--out", str(tmp_path / "o"), as_user=True)
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip() == f"convodrive: error: {locked}: cannot read (permission denied)"


@pytest.mark.mujoco
def test_profile_names_resolve_the_same_everywhere(tone_dialogue: Path, tmp_path: Path) -> None:
    """Defect 19: `drive --config servo_head` said "no such config file" while the servo tools
    accepted the name; from any folder, a bundled profile is named, a file is a path."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = run_cli(
        "drive", str(tone_dialogue), "--backend", "mujoco", "--config", "servo_head",
        "-B", "mujoco.video=false", "--out", str(tmp_path / "o"), cwd=elsewhere,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    report = json.loads((tmp_path / "o" / "run_report.json").read_text())
    assert report["config"] == "servo_head"
    assert report["backends"]["mujoco"]["report"]["model"].endswith("servo_head.xml")
    missing = run_cli(
        "drive", str(tone_dialogue), "--config", "servo_haed", "--out", str(tmp_path / "p"), cwd=elsewhere
    )
    assert missing.returncode == 2
    assert "unknown robot profile 'servo_haed'" in missing.stderr and "servo_head" in missing.stderr


@pytest.mark.hardware
def test_plugins_name_lists_options(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["plugins", "dynamixel"]) == 0
    out = capsys.readouterr().out
    assert "backend dynamixel:" in out and "-B dynamixel.KEY=VALUE" in out
    lines = out.splitlines()
    i = next(k for k, line in enumerate(lines) if line.split()[:1] == ["watchdog_s"])
    assert "float, from 0.05 to 10; default 0.5" in lines[i] and "Ease to neutral" in lines[i + 1]
    assert any(line.split()[:1] == ["joints.NAME.id"] and "required" in line for line in lines)
    assert main(["plugins", "record"]) == 0
    assert "stem" in capsys.readouterr().out
    one_line_error(capsys, ["plugins", "mujco"], "unknown plugin 'mujco' (did you mean 'mujoco'?)")


@pytest.mark.mujoco
def test_a_profile_cannot_choose_another_profile(capsys, tone_dialogue: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    profile = tmp_path / "head.yaml"
    text = resolve_profile_path("servo_head").read_text()
    profile.write_text(text.replace("  dynamixel:\n", "  mujoco: {profile: convo_humanoid}\n  dynamixel:\n", 1))
    run = config(tmp_path, f"backends: {{mujoco: {{profile: {profile}}}}}")
    one_line_error(
        capsys,
        drive(tone_dialogue, tmp_path, "--backend", "mujoco", "--config", str(run)),
        f"{profile}: backends.mujoco.profile: a profile cannot choose another",
    )
