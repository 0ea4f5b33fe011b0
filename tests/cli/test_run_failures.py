"""Runs that cannot start or cannot finish, as a user meets them: an ``--out`` that cannot take the
outputs is one line before anything runs; audio that stops decoding part-way ends the run with a
report of what was done; a failed run leaves no empty folder; a killed one no temporary folder."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.backends.base import Backend, Session
from convodrive.motion.npz import load_clip
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.pipeline import DriveRequest, drive
from convodrive.plumbing.errors import UserError
from tests.conftest import run_cli


def _one_line(out: subprocess.CompletedProcess, *needles: str) -> str:
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert "Traceback" not in out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def test_out_that_is_a_file(tone_dialogue: Path, tmp_path: Path) -> None:
    target = tmp_path / "taken"
    target.write_text("keep me")
    _one_line(run_cli("drive", str(tone_dialogue), "--out", str(target)), f"--out {target}: is a file, not a folder")
    assert target.read_text() == "keep me"


def test_out_under_a_file(tone_dialogue: Path, tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("keep me")
    out = tmp_path / "taken" / "deeper" / "out"
    _one_line(run_cli("drive", str(tone_dialogue), "--out", str(out)), f"{tmp_path / 'taken'} is a file, not a folder")


def test_out_not_writable_is_refused_before_the_run(tone_dialogue: Path) -> None:
    # /sys refuses new files even to root: a folder that exists and cannot be written. With -v a
    # backend that opened would log it: one line means the check came before anything ran.
    out = run_cli("drive", str(tone_dialogue), "--out", "/sys", "-v")
    _one_line(out, "--out /sys: cannot write there (permission denied)")
    assert out.stdout == ""
    _one_line(run_cli("drive", str(tone_dialogue), "--out", "/sys/convodrive-out"), "--out /sys/convodrive-out: cannot")


def test_out_without_write_permission(tone_dialogue: Path, tmp_path: Path) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        out = run_cli("drive", str(tone_dialogue), "--out", str(locked), as_user=True)
        _one_line(out, f"--out {locked}: cannot write there (permission denied)")
        out = run_cli("drive", str(tone_dialogue), "--out", str(locked / "sub"), as_user=True)
        _one_line(out, f"--out {locked / 'sub'}: cannot create {locked / 'sub'} (permission denied)")
    finally:
        locked.chmod(0o755)
    assert list(locked.iterdir()) == []


class _RefusesToOpen(Backend):
    """A backend whose configuration turns out wrong only when it opens (a bad port, a bad model)."""

    name = "refuses"

    def open(self, spec: TargetSpec, session: Session) -> None:
        raise UserError("backend refuses: its model file is not a model")

    def send(self, frame: TargetFrame) -> None:
        raise AssertionError("never opened, never sent")


def test_a_run_that_fails_after_making_its_folder_leaves_none(
    tone_dialogue: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from convodrive.pipeline import backends as pipeline_backends

    real = pipeline_backends.load_plugin
    monkeypatch.setattr(
        pipeline_backends, "load_plugin", lambda group, name: _RefusesToOpen if name == "refuses" else real(group, name)
    )
    out = tmp_path / "new" / "out"
    with pytest.raises(UserError, match="refuses"):
        drive(DriveRequest(audio=tone_dialogue, backends=("record", "refuses"), out_dir=out))
    assert not (tmp_path / "new").exists(), "the folders the run made are removed again"
    existing = tmp_path / "existing"
    existing.mkdir()
    with pytest.raises(UserError):
        drive(DriveRequest(audio=tone_dialogue, backends=("refuses",), out_dir=existing))
    assert existing.is_dir(), "a folder the user already had stays"


def _flac(path: Path, seconds: float = 20.0) -> bytes:
    sr = 44_100
    t = np.arange(int(seconds * sr)) / sr
    voice = 0.3 * np.sin(2 * np.pi * 180 * t) * (0.6 + 0.4 * np.sin(2 * np.pi * 3 * t))
    sf.write(path, np.stack([voice, 0.5 * voice], 1).astype(np.float32), sr)
    return path.read_bytes()


@pytest.mark.parametrize("damage", ["corrupt", "truncated"])
def test_audio_that_stops_decoding_ends_the_run_with_a_report(tmp_path: Path, damage: str) -> None:
    path = tmp_path / f"{damage}.flac"
    data = bytearray(_flac(path))
    middle = len(data) // 2
    if damage == "corrupt":
        data[middle : middle + 4000] = np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes()
    else:
        del data[middle:]
    path.write_bytes(bytes(data))
    out_dir = tmp_path / "out"
    out = run_cli("drive", str(path), "--out", str(out_dir))
    line = _one_line(out, str(path), "cannot be decoded after", "the run stopped there")
    assert "lost sync" in line
    report = json.loads((out_dir / "run_report.json").read_text())
    assert report["input_error"] and str(path) in report["input_error"]
    assert 0 < report["frames"] < report["expected_frames"]
    assert load_clip(out_dir / "motion.npz").num_frames == report["frames"], "what was done is kept"
    assert "stopped early" in (out_dir / "run_report.txt").read_text()


@pytest.mark.pocketsphinx
def test_a_killed_run_leaves_no_temporary_folder(tmp_path: Path) -> None:
    sr = 16_000
    t = np.arange(sr * 30) / sr
    speechy = 0.3 * np.sin(2 * np.pi * 150 * t) * (np.sin(2 * np.pi * 2 * t) > 0)
    audio = tmp_path / "long.wav"
    sf.write(audio, np.stack([speechy, 0 * t], 1).astype(np.float32), sr)
    scratch, cache = tmp_path / "tmp", tmp_path / "cache"
    scratch.mkdir()
    env = {**os.environ, "TMPDIR": str(scratch), "CONVODRIVE_CACHE_DIR": str(cache)}
    for attempt in range(2):  # the first run makes the phone model, the second finds it made
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "convodrive.cli.main",
                "drive",
                str(audio),
                "--realtime",
                "--out",
                str(tmp_path / "o"),
            ],
            stderr=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        assert proc.stderr is not None
        assert "real time" in proc.stderr.readline()  # running: the phone decoder is loaded
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        assert list(scratch.iterdir()) == [], f"run {attempt}: a killed run leaks {list(scratch.iterdir())}"
    models = list(cache.iterdir())
    assert len(models) == 1 and models[0].name.startswith("phones-") and (models[0] / "mdef").is_file()
