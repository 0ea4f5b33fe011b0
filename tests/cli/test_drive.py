"""``convodrive drive`` as a user meets it: bad input gives one line and code 2; odd but valid
audio runs; Ctrl-C and SIGTERM end a run cleanly with complete outputs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.motion.npz import load_clip
from tests.conftest import run_cli


def _assert_one_line_error(out: subprocess.CompletedProcess, *needles: str) -> None:
    assert out.returncode == 2, (out.returncode, out.stderr)
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, f"expected one line, got: {out.stderr!r}"
    assert "Traceback" not in out.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_missing_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.wav"
    _assert_one_line_error(run_cli("drive", str(missing), "--out", str(tmp_path / "o")), str(missing), "no such file")


def test_corrupt_wav(tmp_path: Path) -> None:
    bad = tmp_path / "corrupt.wav"
    bad.write_bytes(b"RIFF\x24\x00\x00\x00WAVEfmt " + os.urandom(200))
    _assert_one_line_error(
        run_cli("drive", str(bad), "--out", str(tmp_path / "o")), str(bad), "not a readable audio file"
    )


def test_empty_file(tmp_path: Path) -> None:
    empty = tmp_path / "empty.wav"
    empty.write_bytes(b"")
    _assert_one_line_error(run_cli("drive", str(empty), "--out", str(tmp_path / "o")), str(empty), "empty")


def test_text_file_named_wav(tmp_path: Path) -> None:
    text = tmp_path / "notes.wav"
    text.write_text("this is not audio\n" * 20)
    _assert_one_line_error(run_cli("drive", str(text), "--out", str(tmp_path / "o")), str(text))


def test_nan_samples(tmp_path: Path) -> None:
    path = tmp_path / "nan.wav"
    data = np.zeros((16000, 2), np.float32)
    data[5000, 0] = np.nan
    sf.write(path, data, 16000, subtype="FLOAT")
    _assert_one_line_error(run_cli("drive", str(path), "--out", str(tmp_path / "o")), str(path), "NaN")


def test_four_channels_need_a_choice_then_run(tmp_path: Path) -> None:
    path = tmp_path / "four.wav"
    t = np.arange(16000 * 2) / 16000
    voice = (0.3 * np.sin(2 * np.pi * 160 * t)).astype(np.float32)
    sf.write(path, np.stack([voice * 0, voice * 0, voice, voice * 0], axis=1), 16000)
    _assert_one_line_error(run_cli("drive", str(path), "--out", str(tmp_path / "o")), str(path), "--channels")
    out = run_cli("drive", str(path), "--channels", "2,3", "--out", str(tmp_path / "o"))
    assert out.returncode == 0, out.stderr
    report = json.loads((tmp_path / "o" / "run_report.json").read_text())
    assert report["audio"]["self_channel"] == 2 and report["audio"]["other_channel"] == 3
    assert report["frames"] == 60


def test_96khz_mono_runs_with_a_silent_partner(tmp_path: Path) -> None:
    path = tmp_path / "hires.wav"
    sr = 96_000
    t = np.arange(int(sr * 1.5)) / sr
    sf.write(path, (0.3 * np.sin(2 * np.pi * 200 * t)).astype(np.float32), sr)
    out = run_cli("drive", str(path), "--out", str(tmp_path / "o"))
    assert out.returncode == 0, out.stderr
    clip = load_clip(tmp_path / "o" / "motion.npz")
    assert clip.num_frames == 45
    assert np.all(clip.vad[:, 1] == 0), "mono audio means the partner never speaks"


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--backend", "nosuch"], "unknown backend 'nosuch'"),
        (["--generator", "nosuch"], "unknown generator 'nosuch'"),
        (["--samples", "0"], "--samples"),
        (["--channels", "x,y"], "--channels"),
        (["--realtime", "--offline"], "not allowed with"),
    ],
)
def test_bad_options(tone_dialogue: Path, tmp_path: Path, args: list[str], needle: str) -> None:
    _assert_one_line_error(run_cli("drive", str(tone_dialogue), "--out", str(tmp_path / "o"), *args), needle)


def test_bad_config_names_the_file(tone_dialogue: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "broken.yaml"
    cfg.write_text("generator: [unclosed\n")
    _assert_one_line_error(
        run_cli("drive", str(tone_dialogue), "--config", str(cfg), "--out", str(tmp_path / "o")), str(cfg)
    )


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_ends_the_run_with_complete_outputs(tmp_path: Path, sig: int) -> None:
    path = tmp_path / "long.wav"
    sr = 16_000
    t = np.arange(sr * 30) / sr
    sf.write(path, np.stack([0.3 * np.sin(2 * np.pi * 150 * t)] * 2, axis=1).astype(np.float32), sr)
    out_dir = tmp_path / "o"
    proc = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "drive", str(path), "--realtime", "--out", str(out_dir)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    started = proc.stderr.readline()  # printed once the 30 fps clock runs: signals now hit the run
    assert "real time" in started, started
    time.sleep(1.0)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, stderr  # the shell's convention: 130 for SIGINT, 143 for SIGTERM
    assert "Traceback" not in stderr
    report = json.loads((out_dir / "run_report.json").read_text())
    assert report["interrupted"] is True
    assert 0 < report["frames"] < 900
    clip = load_clip(out_dir / "motion.npz")
    assert clip.num_frames == report["frames"]
    assert not list(out_dir.glob(".*")), "no temporary files are left behind"


def _video_frames(path: Path) -> int:
    out = subprocess.run(
        [
            "ffprobe",
            "-v",
            "error",
            "-count_frames",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=nb_read_frames",
            "-of",
            "csv=p=0",
            str(path),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(out.stdout.strip())


def test_ctrl_c_to_the_process_group_leaves_every_process_backend_complete(tmp_path: Path) -> None:
    """Ctrl-C in a terminal reaches the whole process group, the backends' own processes too: they
    must leave it to the run, which stops the clock, lets them take the frames already made, and
    closes them; the videos end complete, one frame per frame of the run."""
    path = tmp_path / "long.wav"
    sr = 16_000
    t = np.arange(sr * 30) / sr
    sf.write(path, np.stack([0.3 * np.sin(2 * np.pi * 150 * t)] * 2, axis=1).astype(np.float32), sr)
    out_dir = tmp_path / "o"
    args = ["drive", str(path), "--realtime", "--backend", "record,render,mujoco", "--out", str(out_dir)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a shell gives a foreground job
    )
    assert proc.stderr is not None
    assert "real time" in proc.stderr.readline()
    time.sleep(2.0)
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    report = json.loads((out_dir / "run_report.json").read_text())
    assert report["interrupted"] is True and report["stop_signal"] == "SIGINT"
    frames = report["frames"]
    assert 30 < frames < 900
    for name, video in (("render", "avatar.mp4"), ("mujoco", "mujoco.mp4")):
        entry = report["backends"][name]
        assert entry["report"]["process"]["exit"] == "exit code 0", "it ran in its own process and closed"
        assert entry["frames_sent"] == frames and entry["errors"] == 0 and not entry["close_error"]
        assert _video_frames(out_dir / video) == frames, video
    assert load_clip(out_dir / "motion.npz").num_frames == frames
    assert not list(out_dir.glob(".*")), "no temporary files are left behind"
    leftover = subprocess.run(["pgrep", "-s", str(proc.pid)], capture_output=True, text=True).stdout.split()
    assert not leftover, "no process of the run outlives it"


def test_a_degraded_backend_says_why(tone_dialogue: Path, tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    out = subprocess.run(
        [sys.executable, "-m", "convodrive.cli.main", "drive", str(tone_dialogue), "--backend", "render",
         "-B", "render.window=true", "-B", "render.resolution=64x64", "--out", str(tmp_path / "o")],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    line = next(line for line in out.stdout.splitlines() if line.strip().startswith("render"))
    assert "degraded" in line and "no display" in line, line
