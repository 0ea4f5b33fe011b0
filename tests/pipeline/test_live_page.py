"""The issue's must-show run: ``convodrive live --partner PARTNER.wav --self SELF.wav --backend
dynamixel,stream`` against the Dynamixel emulator and a virtual sink, with the live page open in
headless Chromium."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.backends.chromium import Chromium
from tests.conftest import REPO
from tests.pulse import MONITOR, SPEAKER, dialogue_halves

pytestmark = [pytest.mark.pulseaudio, pytest.mark.live, pytest.mark.chromium, pytest.mark.hardware]

ARTIFACTS = REPO / "test-artifacts"


def face_crop(image: np.ndarray, face: str) -> np.ndarray:
    x, y, r = (int(v) for v in face.split(","))
    return image[max(y - r, 0) : y + r, max(x - r, 0) : x + r].astype(np.float32)


@pytest.mark.slow
def test_live_run_into_servo_head_and_browser_page(pulse, tmp_path: Path) -> None:
    self_wav, partner_wav = dialogue_halves(tmp_path / "in", seconds=12.0)
    emulator = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "emulate", "dynamixel", "--ids", "1-7"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    out = tmp_path / "out"
    run = chromium = None
    try:
        assert emulator.stdout is not None
        port = emulator.stdout.readline().strip()
        run = subprocess.Popen(
            [sys.executable, "-m", "convodrive.cli.main", "live", "--partner", str(partner_wav), "--self", str(self_wav),
             "--backend", "dynamixel,stream", "--play", SPEAKER, "--monitor", MONITOR,
             "-B", f"dynamixel.port={port}", "-B", "stream.port=0", "--out", str(out)],
            env={**os.environ, **pulse.env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert run.stderr is not None
        url = next(line.split(" at ", 1)[1].strip() for line in run.stderr if "the live page is at" in line)
        chromium = Chromium(tmp_path / "chromium")
        chromium.call("Page.navigate", url=url)
        chromium.wait_for("document.body.dataset.connected === 'true' && document.body.dataset.avatar === 'loaded'")
        # Two screenshots a second apart while the robot is talking (self speaks from 0.8 s to 4.9 s
        # and from 8.2 s to 12 s): the face must have moved.
        chromium.wait_for(
            "[[30, 80], [250, 300]].some(([a, b]) => +document.body.dataset.frame >= a && +document.body.dataset.frame <= b)"
        )
        face = chromium.evaluate("document.body.dataset.face")
        started = time.monotonic()
        frames = [chromium.evaluate("+document.body.dataset.frame")]
        first_png, first = chromium.screenshot()
        time.sleep(max(0.0, started + 1.0 - time.monotonic()))  # a capture takes about half a second
        frames.append(chromium.evaluate("+document.body.dataset.frame"))
        elapsed = time.monotonic() - started
        second_png, second = chromium.screenshot()
        received = chromium.evaluate("+document.body.dataset.frames")
        stdout, stderr = run.communicate(timeout=120)
    except AssertionError as failure:  # say what the live run said: a page that cannot connect means it stopped
        said = ""
        if run is not None:
            if run.poll() is None:
                run.terminate()
            said = run.communicate(timeout=30)[1][-3000:]
        code = None if run is None else run.returncode
        raise AssertionError(f"{failure}\nthe live run (exit {code}) said:\n{said}") from None
    finally:
        for proc in (run, emulator):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=30)
        if chromium is not None:
            chromium.close()
    ARTIFACTS.mkdir(exist_ok=True)
    for name, png in (("live_page.png", first_png), ("live_page_1s_later.png", second_png)):
        (tmp_path / name).write_bytes(png)
        shutil.copyfile(tmp_path / name, ARTIFACTS / name)

    a, b = face_crop(first, face), face_crop(second, face)
    assert a.shape == b.shape and a.size > 40 * 40 * 3, face
    assert a.std() > 20.0, "the crop shows a face, not the empty background"
    assert np.abs(a - b).mean() > 1.5, "the face moved in a second of speech"
    # Apart in the motion too. A page starved by the capture and a loaded 2-core machine draws late
    # (19 of 30 frames in a full-suite run), so this asks for a third of real time, not all of it:
    # a page that stopped drawing, or redraws one frame, fails.
    assert frames[1] - frames[0] >= 10 * elapsed, f"the page went on drawing new frames: {frames} in {elapsed:.2f} s"
    assert received >= frames[1] - frames[0], "the page counts the frames it received"

    assert run.returncode == 0, stderr
    report = json.loads((out / "run_report.json").read_text())
    dynamixel = report["backends"]["dynamixel"]
    assert dynamixel["report"]["torque_off"] is True, "servos eased to neutral and torque went off"
    assert report["backends"]["stream"]["report"]["clients"] >= 1
    latency = report["live"]["latency_ms"]
    for backend in ("dynamixel", "stream"):
        assert latency["partner_capture_to_sent"][backend]["p99"] > 0
    assert abs(report["live"]["audio_motion_offset"]["median_ms"]) <= 1000.0 / 30
    assert "partner_capture_to_sent" in (out / "run_report.json").read_text()
    assert "latency" in stdout or "offset" in stdout
