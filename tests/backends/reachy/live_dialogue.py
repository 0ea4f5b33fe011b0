"""The bundled dialogue through ``convodrive live`` into ``reachy_mini``: the partner on a microphone.

Shared by the test (``test_reachy_live.py``) and the bench (``bench/bench_reachy_live.py``). The
audio setup is the live tests' (``tests/pulse.py``): the self voice is the dialogue's channel 0,
read from a file and played on the desk's speaker sink; the partner is channel 1, played in real
time into the room's null sink, whose monitor is the microphone ``convodrive live`` listens to. The
motion goes to Reachy Mini's daemon (``conftest.start_daemon``) on 127.0.0.1.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import soundfile as sf

from tests.backends.reachy.conftest import Daemon
from tests.pulse import MIC, SPEAKER, PulseRig, dialogue_halves


@dataclasses.dataclass
class LiveRun:
    returncode: int
    stderr: str
    report: dict[str, Any] | None
    out: Path

    @property
    def latency(self) -> dict[str, Any] | None:
        """Partner capture (PortAudio's ADC time) to the frame's ``set_full_target`` leaving."""
        assert self.report is not None
        return self.report["live"]["latency_ms"]["partner_capture_to_sent"].get("reachy_mini")

    @property
    def backend(self) -> dict[str, Any]:
        assert self.report is not None
        return dict(self.report["backends"]["reachy_mini"])


def live_dialogue(rig: PulseRig, daemon: Daemon, root: Path, *extra: str, timeout: float = 180) -> LiveRun:
    """One run of the whole dialogue (a microphone never ends: ``--seconds`` is the dialogue's
    length); ``extra``: more ``convodrive live`` arguments."""
    self_wav, partner_wav = dialogue_halves(root / "in")
    seconds = sf.info(str(self_wav)).duration
    out = root / "out"
    live = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "live", "--self", str(self_wav), "--partner", MIC,
         "--play", SPEAKER, "--seconds", f"{seconds:.2f}", "--backend", "reachy_mini", "-B", f"reachy_mini.port={daemon.port}",
         "--out", str(out), *extra],
        env={**os.environ, **rig.env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    talking = None
    try:
        assert live.stderr is not None
        first = live.stderr.readline()  # "live at 30 fps": listening, the partner may start
        if "live at" in first:
            talking = rig.room.play(partner_wav, "room")
        _, rest = live.communicate(timeout=timeout)
    finally:
        for proc in (talking, live):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    report_path = out / "run_report.json"
    report = json.loads(report_path.read_text()) if report_path.exists() else None
    return LiveRun(live.returncode, first + rest, report, out)
