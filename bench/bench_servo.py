"""Servo bus timing through the real dynamixel-sdk and the emulator on a pty; prints JSON.

- ``bus_ms_per_frame``: one SYNC_WRITE of 7 goal positions plus one SYNC_READ of position,
  voltage and temperature from 7 servos at 1 Mbps (wall time, SDK + pty + emulated wire time),
  next to the bytes those packets put on the wire and the wire time alone; with Return_Delay_Time
  0 (what the backend sets) and at the factory 500 us.
- ``frame_to_wire_ms``: from ``DynamixelBackend.send(frame)`` to the emulator receiving the goal
  positions, while the backend's supervisor polls health at 10 Hz, frames at 30 fps.
- The same latency for the Maestro backend.

Run: ``.venv/bin/python bench/bench_servo.py [--frames 300]``
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import platform
import time
from pathlib import Path

import numpy as np

from convodrive.backends.base import Session
from convodrive.backends.dynamixel import HEALTH_REGISTERS, DynamixelBackend
from convodrive.backends.maestro import MaestroBackend
from convodrive.backends.servo.dynamixel_bus import DynamixelBus, Motor
from convodrive.backends.servo.dynamixel_emulator import start_emulated_head
from convodrive.backends.servo.dynamixel_table import model
from convodrive.backends.servo.maestro_emulator import start_emulated_maestro
from convodrive.motion.targets import TargetFrame
from convodrive.retargeting import load_profile

BAUD = 1_000_000
N_SERVOS = 7


def stats(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values)
    return {
        "p50": round(float(np.percentile(arr, 50)), 3),
        "p99": round(float(np.percentile(arr, 99)), 3),
        "mean": round(float(arr.mean()), 3),
        "n": int(arr.size),
    }


def bus_time(frames: int, return_delay_us: int) -> dict[str, object]:
    motors = [Motor(f"j{i}", i, model("xl330")) for i in range(1, N_SERVOS + 1)]
    with start_emulated_head(range(1, N_SERVOS + 1), baudrate=BAUD) as emu:
        bus = DynamixelBus(emu.port, motors, baudrate=BAUD)
        bus.connect()
        for m in motors:
            bus.write("Return_Delay_Time", m.name, return_delay_us // 2)
            bus.write("Torque_Enable", m.name, 1)
        write_ms, read_ms, total_ms = [], [], []
        for k in range(frames):
            goals = {m.name: 2048 + int(200 * np.sin(k / 10 + m.id)) for m in motors}
            t0 = time.perf_counter()
            bus.sync_write("Goal_Position", goals)
            t1 = time.perf_counter()
            got = bus.sync_read(HEALTH_REGISTERS)
            t2 = time.perf_counter()
            assert len(got) == N_SERVOS
            write_ms.append((t1 - t0) * 1e3), read_ms.append((t2 - t1) * 1e3), total_ms.append((t2 - t0) * 1e3)
        bus.disconnect()
        failures = sum(h.timeouts + h.corrupt for h in bus.health.values())
    span = 146 + 1 - 132
    write_bytes = 14 + N_SERVOS * (1 + 4)
    read_bytes = 14 + N_SERVOS + N_SERVOS * (11 + span)
    wire_ms = (write_bytes + read_bytes) * 10 / BAUD * 1e3 + N_SERVOS * return_delay_us / 1e3
    return {
        "servos": N_SERVOS,
        "baudrate": BAUD,
        "return_delay_us": return_delay_us,
        "sync_write_ms": stats(write_ms),
        "sync_read_ms": stats(read_ms),
        "total_ms": stats(total_ms),
        "wire_bytes_per_frame": write_bytes + read_bytes,
        "wire_only_ms": round(wire_ms, 3),
        "comm_failures": failures,
        "budget_share_at_30fps": round(float(np.percentile(total_ms, 99)) / (1000 / 30), 3),
    }


def frame_to_wire(backend_cls, emulator, profile, frames: int, log) -> dict[str, float]:  # type: ignore[no-untyped-def]
    options = profile.backend_options(backend_cls.name)
    options.update(port=emulator.port, read_rate=10, ease_s=0.2)
    backend = backend_cls(options)
    backend.open(profile.spec, Session(out_dir=Path("."), offline=False))
    spec = profile.spec
    sent: list[tuple[float, int]] = []
    start = time.monotonic()
    for i in range(frames):
        t = i / 30
        values = np.clip(
            spec.neutral + 0.2 * np.sin(2 * np.pi * 0.5 * t + np.arange(len(spec.names))) * min(1.0, t),
            spec.lower,
            spec.upper,
        )
        before = len(log())
        sent.append((time.monotonic(), before))
        backend.send(TargetFrame(i, t, values, ()))
        time.sleep(max(0.0, start + (i + 1) / 30 - time.monotonic()))
    backend.close()
    entries = log()
    latency = [(entries[first].time - t_send) * 1e3 for t_send, first in sent if first < len(entries)]
    return stats(latency)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    args = parser.parse_args()
    profile = load_profile("servo_head")
    result: dict[str, object] = {
        "bench": "servo",
        "dynamixel_sdk": importlib.metadata.version("dynamixel-sdk"),
        "python": platform.python_version(),
        "frames": args.frames,
    }
    result["dynamixel_bus_per_frame"] = bus_time(args.frames, 0)  # what the backend configures
    result["dynamixel_bus_per_frame_factory_delay"] = bus_time(args.frames, 500)
    with start_emulated_head() as emu:
        result["dynamixel_frame_to_wire_ms"] = frame_to_wire(
            DynamixelBackend, emu, profile, args.frames, lambda: emu.goal_log
        )
    with start_emulated_maestro(12) as mae:
        result["maestro_frame_to_wire_ms"] = frame_to_wire(
            MaestroBackend, mae, profile, args.frames, lambda: mae.target_log
        )
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
