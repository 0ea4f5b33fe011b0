"""How late a live partner's audio arrives for each capture latency asked of PortAudio; prints JSON.

The setup is the test suite's (``tests/pulse.py``): the bundled dialogue's partner channel is
played into the room sink, whose monitor is the microphone. For each ``--latency``, a
``MicrophoneInput`` (5 ms blocks) is read every 2 ms, as a live run reads it, for ``--seconds``
after ``SETTLE`` seconds of start-up. ``age_ms`` is, per read, how old its first sample is
(capture-to-available, from PortAudio's ADC time): the partner delay must cover it, and reads
older than the run's grace (10 ms) are late blocks. ``read_ms`` is how much audio a read brings:
a server that hands blocks over in bursts brings several at once.

Run: ``.venv/bin/python -m bench.bench_capture [--seconds 30] [--latency 0.02 0.01 0.005]``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from tests.pulse import MIC, PulseRig, dialogue_halves

SETTLE = 3.0
GRACE_MS = 10.0


def measure(latency: float, seconds: float) -> dict[str, Any]:
    from convodrive.audio.live.capture import MicrophoneInput
    from convodrive.audio.live.devices import find_device

    mic = MicrophoneInput(find_device(MIC, "input", "--partner"), ring_seconds=2.0, latency=latency)
    ages, sizes = [], []
    mic.start()
    try:
        started = time.monotonic()
        while (now := time.monotonic()) < started + SETTLE + seconds:
            for data, captured in mic.pull():
                if now >= started + SETTLE:
                    ages.append(1000.0 * (time.monotonic() - captured))
                    sizes.append(1000.0 * len(data) / 16000)
            time.sleep(0.002)
        report = mic.report()
    finally:
        mic.close()
    age = np.asarray(ages)
    return {
        "latency_s": latency,
        "input_latency_ms": report["input_latency_ms"],
        "reads": len(age),
        "read_ms": round(float(np.mean(sizes)), 1),
        "age_ms": {f"p{q}": round(float(np.percentile(age, q)), 1) for q in (50, 90, 99)}
        | {"max": round(float(age.max()), 1)},
        "late_reads": round(float(np.mean(age > GRACE_MS)), 4),
        "overruns": report["overruns"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="seconds measured per setting (default 30)")
    parser.add_argument("--latency", type=float, nargs="+", default=[0.02, 0.01, 0.005], help="capture latencies (s)")
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bench_capture_"))
    rig = PulseRig(root / "pulse")
    os.environ.update(rig.env)  # before PortAudio loads: it finds the rig's devices through HOME
    _, partner = dialogue_halves(root / "voices")
    load_before = os.getloadavg()
    talking = None
    results = []
    try:
        for latency in args.latency:
            if talking is None or talking.poll() is not None:
                talking = rig.room.play(partner, "room")
            results.append(measure(latency, args.seconds))
    finally:
        if talking is not None and talking.poll() is None:
            talking.terminate()
            talking.wait(timeout=10)
        rig.stop()
    print(
        json.dumps(
            {
                "settings": results,
                "grace_ms": GRACE_MS,
                "loadavg_before": [round(x, 2) for x in load_before],
                "loadavg_after": [round(x, 2) for x in os.getloadavg()],
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
