"""``convodrive live`` into ``reachy_mini`` with the partner on a PulseAudio null-sink microphone.

The latency's target (p99 <= 150 ms) lives in ``bench/bench_reachy_live.py``; this test checks
that the run measures it, from the partner's capture to the ``set_full_target`` leaving for the
daemon, for every frame, and that the robot was driven as in a drive.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tests.backends.reachy.conftest import Daemon
from tests.conftest import require

pytestmark = [require("reachy"), pytest.mark.pulseaudio, pytest.mark.live, pytest.mark.slow]

from tests.backends.reachy.live_dialogue import live_dialogue  # noqa: E402
from tests.pulse import PulseRig  # noqa: E402


def test_live_dialogue_partner_on_a_microphone(pulse: PulseRig, reachy_mockup: Daemon, tmp_path: Path) -> None:
    run = live_dialogue(pulse, reachy_mockup, tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.report is not None
    latency, backend = run.latency, run.backend
    report = backend["report"]
    print(json.dumps({"partner_capture_to_set_target_ms": latency, **{k: report[k] for k in ("follow", "liveliness")}}))
    # Every frame that carries partner audio is timed, to when its set_full_target left (send's return).
    frames = run.report["frames"]
    assert latency is not None and latency["count"] >= 0.75 * frames, (latency, frames)
    assert 0 < latency["p50"] <= latency["p99"] and math.isfinite(latency["p99"]), latency
    partner = run.report["live"]["partner"]
    assert not partner["lost"], (partner["lost"], partner["longest_callback_gap_ms"], partner.get("events"))
    assert latency["p50"] >= run.report["generator"]["lookahead_ms"], "a frame waits for its look-ahead"
    # The partner was heard (listening frames) and the robot was driven as in a drive.
    heard = report["liveliness"]["commanded"]
    assert heard["listening"]["seconds"] + heard["overlap"]["seconds"] >= 4, heard
    assert report["status"] == "ok", report.get("reason")
    assert report["commands_outside_limits"] == 0 and report["unsent"] == 0 and report["disconnects"] == 0
    assert report["frames"] == backend["frames_sent"] >= 0.9 * frames, (
        report["frames"],
        backend["frames_sent"],
        frames,
    )
    assert report["eased_to_neutral"]
