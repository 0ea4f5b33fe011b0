"""A live conversation on real audio devices, timed end to end; prints JSON.

The setup is the test suite's (``tests/pulse.py``): two private PulseAudio servers with null
sinks. The self voice (the bundled dialogue's channel 0, repeated to ``--seconds``) is played on
the speaker sink; its monitor is recorded (``--monitor``); the partner (channel 1, repeated) is
played into the room sink, whose monitor is the microphone ``convodrive live`` listens to. The
motion drives an emulated 7-servo Dynamixel head (``convodrive emulate dynamixel`` on a pty)
through the real SDK with the ``procedural`` generator.

- ``partner_latency_ms``: from a partner sample's capture (PortAudio's ADC time) to the servo goal
  written on the bus for the frame it belongs to (p50, p99, max).
- ``offset_ms``: speech onsets heard at the speaker's monitor against the mouth openings sent,
  over the whole run, and in its first and last minute (``offset_by_minute``). ``sync_error_ms``
  leaves out the generator's own offset (what it does on purpose); ``drift_frames`` is the change
  of that clock error from the first minute to the last, in frames (30 fps).
- Targets: offset within ±33 ms, drift 0 frames over 10 minutes, partner latency <= 150 ms p99.
  The partner's latency is at least the generator's look-ahead: ``procedural`` needs 115 ms
  plus its ``anticipation`` (``convodrive live`` makes it 0 unless ``-G`` says otherwise).

Run: ``.venv/bin/python -m bench.bench_live [--seconds 600] [-G anticipation=0.3]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import soundfile as sf

from convodrive.eval.sync import level_db, mouth_onsets, pair_onsets, speech_onsets
from convodrive.samples import bundled_dialogue
from tests.pulse import MIC, MONITOR, SPEAKER, PulseRig

TARGETS = {"offset_ms": 33.0, "drift_frames": 0, "partner_latency_p99_ms": 150.0}


def repeated_halves(seconds: float, out: Path) -> tuple[Path, Path]:
    data, rate = sf.read(bundled_dialogue(), dtype="float32")
    reps = int(np.ceil(seconds * rate / len(data)))
    data = np.tile(data, (reps, 1))[: int(seconds * rate)]
    paths = out / "self.wav", out / "partner.wav"
    for channel, path in enumerate(paths):
        sf.write(path, np.ascontiguousarray(data[:, channel]), rate, subtype="PCM_16")
    return paths


def minute_offsets(run_dir: Path) -> dict[str, float | int | None]:
    """Median offsets of the first and last minute, from the run's own evidence.

    The offset heard at the monitor is the generator's own (its mouth opens a little before or
    after a speech onset, by design and by content) plus the clock's error. The dialogue repeats,
    so a minute's own offset depends on which of its sentences the minute holds: over 10 minutes it
    alternated between -2 and -11 ms here, and so did the heard offset. The drift is taken from
    the clock's part alone: each minute's heard median less its own median.
    """
    evidence = np.load(run_dir / "sync.npz")
    monitor = evidence["monitor"].astype(np.float32) / 32768.0
    rate = int(evidence["monitor_rate"])
    onsets = (speech_onsets(level_db(monitor, rate)) * rate).astype(int)
    heard = np.interp(onsets, evidence["monitor_index"], evidence["monitor_mono"])
    shown = evidence["frame_dispatch_mono"][mouth_onsets(evidence["jaw_open"])]
    figure = pair_onsets(heard, shown)
    own = pair_onsets(speech_onsets(evidence["self_level_db"]), mouth_onsets(evidence["jaw_open"]) / 30)
    if not len(figure.times) or not len(own.times):
        return {"first_minute_ms": None, "last_minute_ms": None}

    def minute(times: np.ndarray, offsets: np.ndarray, last: bool) -> np.ndarray:
        return offsets[times > times.max() - 60] if last else offsets[times < times.min() + 60]

    out: dict[str, float | int | None] = {}
    for name, last in (("first", False), ("last", True)):
        heard_ms = minute(figure.times, figure.offsets_ms, last)
        own_ms = minute(own.times, own.offsets_ms, last)
        out[f"{name}_minute_ms"] = round(float(np.median(heard_ms)), 1)
        out[f"{name}_minute_own_ms"] = round(float(np.median(own_ms)), 1)
        out[f"{name}_minute_clock_ms"] = round(float(np.median(heard_ms) - np.median(own_ms)), 1)
        out[f"pairs_{name}_minute"] = int(len(heard_ms))
    return out


def run(seconds: float, generator_options: list[str]) -> dict[str, object]:
    root = Path(tempfile.mkdtemp(prefix="bench_live_"))
    load_before = os.getloadavg()
    rig = PulseRig(root / "pulse")
    emulator = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "emulate", "dynamixel", "--ids", "1-7"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    talking = live = None
    try:
        assert emulator.stdout is not None
        port = emulator.stdout.readline().strip()
        self_wav, partner_wav = repeated_halves(seconds, root)
        out = root / "run"
        env = {**os.environ, **rig.env}
        live = subprocess.Popen(
            [sys.executable, "-m", "convodrive.cli.main", "live", "--self", str(self_wav), "--partner", MIC,
             "--play", SPEAKER, "--monitor", MONITOR, "--seconds", str(seconds), "--backend", "dynamixel",
             "-B", f"dynamixel.port={port}", "--out", str(out), *[a for g in generator_options for a in ("-G", g)]],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert live.stderr is not None
        live.stderr.readline()  # "live at 30 fps": the partner may start talking
        talking = rig.room.play(partner_wav, "room")
        stdout, stderr = live.communicate(timeout=seconds + 120)
        if live.returncode != 0:
            raise RuntimeError(f"convodrive live failed ({live.returncode}): {stderr[-2000:]}")
        report = json.loads((out / "run_report.json").read_text())
    finally:
        for proc in (talking, live, emulator):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=10)
        rig.stop()
    info = report["live"]
    offset = info["audio_motion_offset"]
    minutes = minute_offsets(out)
    first, last = minutes.get("first_minute_clock_ms"), minutes.get("last_minute_clock_ms")
    drift_ms = None if first is None or last is None else last - first
    latency = info["latency_ms"]["partner_capture_to_sent"].get("dynamixel")
    dxl = report["backends"]["dynamixel"]
    return {
        "seconds": seconds,
        "generator": report["generator"],
        "frames": report["frames"],
        "partner_latency_ms": latency,
        "partner_delay_ms": info["latency_ms"]["partner_delay"],
        "partner_capture_to_available_ms": info["partner"].get("capture_to_available_ms"),
        "dispatch_to_goal_ms": dxl["dispatch_to_sent_ms"],
        "offset_ms": {k: offset.get(k) for k in ("median_ms", "mean_ms", "min_ms", "max_ms", "pairs")},
        "offset_by_minute": minutes,
        "drift_frames": None if drift_ms is None else round(drift_ms * 30 / 1000, 2),
        "offset_trend_ms_per_10min": offset.get("drift_ms_per_10min"),
        "sync_error_ms": info["sync_error_ms"],
        "generator_offset_ms": info["generator_offset"].get("median_ms"),
        "clock": {
            "late_frames": report["late_frames"],
            "jitter_ms": report["jitter_ms"],
            "dispatch_drift_frames": report["drift_frames"],
        },
        "playback": info["playback"],
        "partner": {
            k: info["partner"].get(k)
            for k in ("resyncs", "late_blocks", "late_ms", "late_dropped_ms", "lost", "overruns")
        },
        "servo": {"torque_off": dxl["report"].get("torque_off"), "status": dxl["health"].get("status")},
        "targets": TARGETS,
        "loadavg_before": [round(x, 2) for x in load_before],
        "loadavg_after": [round(x, 2) for x in os.getloadavg()],
        "run_dir": str(out),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="length of the conversation (default 600)")
    parser.add_argument(
        "-G", dest="generator_options", action="append", default=[], metavar="KEY=VALUE",
        help="a procedural option, e.g. -G anticipation=0.3 (live runs use 0: a 115 ms look-ahead)",
    )  # fmt: skip
    args = parser.parse_args()
    started = time.time()
    result = run(args.seconds, args.generator_options)
    result["bench_wall_s"] = round(time.time() - started, 1)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
