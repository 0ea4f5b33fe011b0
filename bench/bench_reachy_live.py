"""The dialogue live into Reachy Mini's daemon, the partner on a microphone, timed; prints JSON.

The setup is the test's (``tests/backends/reachy/live_dialogue.py``): two private PulseAudio
servers with null sinks (``tests/pulse.py``); the self voice (the bundled dialogue's channel 0)
from a file, played on the speaker sink; the partner (channel 1) played in real time into the room
sink, whose monitor is the microphone ``convodrive live`` listens to; the motion into
``--backend reachy_mini`` against the real daemon in its mockup simulation on 127.0.0.1
(``.venv-reachy``, ``scripts/setup.sh --dev``), mDNS stubbed and telemetry off.

- ``partner_latency_ms``: from a partner sample's capture (PortAudio's ADC time) to the
  ``set_full_target`` of the frame it belongs to leaving for the daemon (p50, p99, max). It is at
  least the generator's look-ahead (``procedural``: 115 ms with ``convodrive live``'s anticipation 0).
- ``set_target_ms``: the cost of one send; ``follow``: the read-back's lag and tracking error.
- Target: partner latency p99 <= 150 ms (issue 34).

Run: ``.venv/bin/python -m bench.bench_reachy_live [--runs 1]``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from tests.backends.reachy.conftest import start_daemon, stop_daemon
from tests.backends.reachy.live_dialogue import live_dialogue
from tests.pulse import PulseRig

TARGETS = {"partner_latency_p99_ms": 150.0}


def one_run(root: Path) -> dict[str, Any]:
    daemon = start_daemon(root / "daemon", ["--mockup-sim"])
    rig = None
    try:
        rig = PulseRig(root / "pulse")
        run = live_dialogue(rig, daemon, root)
    finally:
        if rig is not None:
            rig.stop()
        stop_daemon(daemon)
    if run.returncode != 0 or run.report is None:
        raise RuntimeError(f"convodrive live failed ({run.returncode}): {run.stderr[-2000:]}")
    report, backend = run.report, run.backend
    latency = run.latency or {}
    return {
        "frames": report["frames"],
        "partner_latency_ms": latency,
        "meets_target": latency.get("p99", float("inf")) <= TARGETS["partner_latency_p99_ms"],
        "lookahead_ms": report["generator"].get("lookahead_ms"),
        "partner_delay_ms": report["live"]["latency_ms"]["partner_delay"],
        "partner_capture_to_generated_ms": report["live"]["latency_ms"]["partner_capture_to_generated"],
        "generated_to_dispatched_ms": report["live"]["latency_ms"]["generated_to_dispatched"],
        "dispatch_to_sent_ms": backend["dispatch_to_sent_ms"],
        "set_target_ms": backend["report"]["set_target_ms"],
        "commands_per_s": backend["report"]["commands_per_s"],
        "follow": backend["report"]["follow"],
        "liveliness_readback": backend["report"]["liveliness"].get("readback"),
        "status": backend["report"]["status"],
        "late_frames": report["late_frames"],
        "jitter_ms": report["jitter_ms"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1, help="runs of the whole dialogue (about 26 s each)")
    args = parser.parse_args()
    started = time.time()
    load_before = os.getloadavg()
    runs = [one_run(Path(tempfile.mkdtemp(prefix="bench_reachy_live_"))) for _ in range(args.runs)]
    print(
        json.dumps(
            {
                "runs": runs,
                "targets": TARGETS,
                "loadavg_before": [round(x, 2) for x in load_before],
                "loadavg_after": [round(x, 2) for x in os.getloadavg()],
                "bench_wall_s": round(time.time() - started, 1),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
