"""Feetech bus time per frame through the real scservo_sdk and the emulator on a pty; prints JSON.

One frame's bus work is what the ``feetech`` backend does: one SYNC_WRITE of 7 goal positions and
one SYNC_READ of position, load, voltage and temperature from 7 STS3215s at 1 Mbps. The wall time
(SDK, pty, and the emulator's wire time) stands next to the wire time alone: the bytes those
packets put on the bus (framed by ``feetech_packet``) x 10 bits / baud, plus each servo's
Return_Delay_Time; with that delay 0 (what the backend sets) and at the factory 500 us.

Run: ``.venv/bin/python -m bench.bench_feetech [--frames 300]``
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import platform
import time

import numpy as np

from bench.bench_servo import stats
from bench.machine import cpu_name
from convodrive.backends.feetech import HEALTH_REGISTERS
from convodrive.backends.servo import feetech_packet as fp
from convodrive.backends.servo import feetech_table as ft
from convodrive.backends.servo.feetech_bus import FeetechBus, Motor
from convodrive.backends.servo.feetech_emulator import start_emulated_feetech

BAUD = 1_000_000
N_SERVOS = 7


def wire_bytes() -> int:
    """Bytes on the wire for one frame: the SYNC_WRITE, the SYNC_READ and its seven replies."""
    regs = [ft.STS.reg(r) for r in HEALTH_REGISTERS]
    start = min(r.address for r in regs)
    span = max(r.address + r.size for r in regs) - start
    goal = ft.STS.reg("Goal_Position")
    write = fp.instruction(fp.BROADCAST_ID, fp.SYNC_WRITE, bytes([goal.address, goal.size] + [0] * 3 * N_SERVOS))
    read = fp.instruction(fp.BROADCAST_ID, fp.SYNC_READ, bytes([start, span] + [0] * N_SERVOS))
    reply = fp.status(1, 0, bytes(span))
    return len(write) + len(read) + N_SERVOS * len(reply)


def bus_time(frames: int, return_delay_us: int) -> dict[str, object]:
    motors = [Motor(f"j{i}", i, ft.model("sts3215")) for i in range(1, N_SERVOS + 1)]
    with start_emulated_feetech(range(1, N_SERVOS + 1), baudrate=BAUD) as emu:
        bus = FeetechBus(emu.port, motors, baudrate=BAUD)
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
        failures = sum(h.timeouts + h.corrupt + h.short for h in bus.health.values())
    nbytes = wire_bytes()
    wire_ms = nbytes * 10 / BAUD * 1e3 + N_SERVOS * return_delay_us / 1e3
    return {
        "servos": N_SERVOS,
        "baudrate": BAUD,
        "return_delay_us": return_delay_us,
        "sync_write_ms": stats(write_ms),
        "sync_read_ms": stats(read_ms),
        "total_ms": stats(total_ms),
        "wire_bytes_per_frame": nbytes,
        "wire_only_ms": round(wire_ms, 3),
        "overhead_p50_ms": round(float(np.percentile(total_ms, 50)) - wire_ms, 3),
        "comm_failures": failures,
        "budget_share_at_30fps": round(float(np.percentile(total_ms, 99)) / (1000 / 30), 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    args = parser.parse_args()
    result: dict[str, object] = {
        "bench": "feetech",
        "feetech_servo_sdk": importlib.metadata.version("feetech-servo-sdk"),
        "python": platform.python_version(),
        "cpu": cpu_name(),
        "frames": args.frames,
        "bus_per_frame": bus_time(args.frames, 0),  # what the backend configures
        "bus_per_frame_factory_delay": bus_time(args.frames, 500),
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
