"""``livelink``: Live Link Face packets, decoded here byte by byte as Unreal's plugin reads them."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX
from convodrive.motion.livelink import head_eye_rotations
from convodrive.motion.npz import load_clip
from tests.backends.udp_listener import UdpListener, closed_port
from tests.conftest import run_cli

pytestmark = [pytest.mark.espeak]


def decode(packet: bytes) -> dict:
    """The app's layout, big-endian: version byte, device id and subject (int32 length + UTF-8),
    frame number, sub-frame, rate numerator and denominator, a count byte, then the floats."""
    version = packet[0]
    (n,) = struct.unpack(">i", packet[1:5])
    device = packet[5 : 5 + n].decode()
    pos = 5 + n
    (m,) = struct.unpack(">i", packet[pos : pos + 4])
    subject = packet[pos + 4 : pos + 4 + m].decode()
    pos += 4 + m
    frame, sub, num, den, count = struct.unpack(">ifiiB", packet[pos : pos + 17])
    values = np.frombuffer(packet[pos + 17 :], dtype=">f4")
    assert len(values) == count
    return {
        "version": version,
        "device": device,
        "subject": subject,
        "frame": frame,
        "rate": (num, den),
        "values": values,
    }


def test_packets_carry_the_recorded_face_and_head(tmp_path: Path, talk: Path) -> None:
    listener = UdpListener()
    try:
        done = run_cli(
            "drive", str(talk), "--backend", "livelink,record", "--out", str(tmp_path),
            "-B", f"livelink.port={listener.port}", "-B", "livelink.subject=RobotFace",
        )  # fmt: skip
    finally:
        packets = listener.close()
    assert done.returncode == 0, done.stderr
    clip = load_clip(tmp_path / "motion.npz")
    decoded = {p["frame"]: p for p in map(decode, packets)}
    assert len(decoded) >= 0.95 * clip.num_frames, "one datagram a frame (UDP on loopback loses next to none)"
    first = next(iter(decoded.values()))
    assert first["version"] == 6 and first["subject"] == "RobotFace" and first["rate"] == (30, 1)
    assert len(first["values"]) == 61
    rotations = head_eye_rotations(clip.pose)
    for frame, packet in decoded.items():
        np.testing.assert_array_equal(
            packet["values"][:52], clip.face[frame, [BLENDSHAPE_INDEX[n] for n in ARKIT_NAMES]]
        )
        np.testing.assert_allclose(packet["values"][52:], rotations[frame], atol=1e-6)
    jaw = np.array([p["values"][ARKIT_NAMES.index("jawOpen")] for p in decoded.values()])
    assert jaw.max() > 0.2, "the mouth moved in what was sent"


def test_unknown_host_is_one_line(tmp_path: Path, talk: Path) -> None:
    done = run_cli(
        "drive", str(talk), "--backend", "livelink", "--out", str(tmp_path), "-B", "livelink.host=no.such.host.invalid"
    )
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "livelink" in done.stderr and "no.such.host.invalid" in done.stderr


def test_a_receiver_that_is_not_there_fails_the_run(tmp_path: Path, talk: Path) -> None:
    """Unreal not listening on loopback: each packet after the first is refused, the report says
    livelink FAILED, and with no other body the run exits 3; beside a body that works, it exits 0."""
    port = closed_port()
    done = run_cli(
        "drive", str(talk), "--backend", "livelink", "--out", str(tmp_path / "a"), "-B", f"livelink.port={port}"
    )
    assert done.returncode == 3, done.stderr
    report = json.loads((tmp_path / "a" / "run_report.json").read_text())
    assert report["backends"]["livelink"]["errors"] >= 30
    assert "livelink   FAILED" in (tmp_path / "a" / "run_report.txt").read_text()
    done = run_cli(
        "drive", str(talk), "--backend", "livelink,record", "--out", str(tmp_path / "b"), "-B", f"livelink.port={port}"
    )
    assert done.returncode == 0, done.stderr
    assert "livelink   FAILED" in (tmp_path / "b" / "run_report.txt").read_text()
