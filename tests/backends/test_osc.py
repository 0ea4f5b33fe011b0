"""``osc``: one bundle a frame, decoded here from the OSC 1.0 byte layout (not with python-osc)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from convodrive.motion import rotations
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.npz import load_clip
from convodrive.motion.skeleton import JOINT_NAMES
from tests.backends.udp_listener import UdpListener, closed_port
from tests.conftest import run_cli

pytestmark = [pytest.mark.live, pytest.mark.espeak]


def _string(data: bytes, pos: int) -> tuple[str, int]:
    end = data.index(b"\0", pos)
    return data[pos:end].decode(), (end + 4) // 4 * 4  # NUL-terminated, padded to 4 bytes


def decode_bundle(data: bytes) -> dict[str, list]:
    """``#bundle``, an 8-byte time tag, then size-prefixed messages: address, type tags, arguments."""
    tag, pos = _string(data, 0)
    assert tag == "#bundle"
    pos += 8
    messages: dict[str, list] = {}
    while pos < len(data):
        (size,) = struct.unpack(">i", data[pos : pos + 4])
        message = data[pos + 4 : pos + 4 + size]
        pos += 4 + size
        address, at = _string(message, 0)
        types, at = _string(message, at)
        assert types.startswith(",")
        args = []
        for t in types[1:]:
            args.append(struct.unpack(">f" if t == "f" else ">i", message[at : at + 4])[0])
            at += 4
        messages[address] = args
    return messages


@pytest.mark.parametrize("rotation", ["quaternion", "euler"])
def test_bundles_carry_every_channel_and_joint(tmp_path: Path, talk: Path, rotation: str) -> None:
    listener = UdpListener()
    try:
        done = run_cli(
            "drive", str(talk), "--backend", "osc,record", "--out", str(tmp_path),
            "-B", f"osc.port={listener.port}", "-B", f"osc.rotation={rotation}",
        )  # fmt: skip
    finally:
        bundles = [decode_bundle(d) for d in listener.close()]
    assert done.returncode == 0, done.stderr
    clip = load_clip(tmp_path / "motion.npz")
    assert len(bundles) >= 0.95 * clip.num_frames
    assert all(len(b) == 52 + 55 + 2 for b in bundles), "one message per channel and joint, vad and state"
    # Bundles carry no frame number: match each to its frame by the face it carries.
    face = np.array([[b[f"/convodrive/face/{n}"][0] for n in ARKIT_NAMES] for b in bundles])
    frames = [int(np.argmin(np.abs(clip.face - f).sum(axis=1))) for f in face]
    np.testing.assert_allclose(face, clip.face[frames], atol=1e-6)
    assert face[:, ARKIT_NAMES.index("jawOpen")].max() > 0.2
    for bundle, frame in zip(bundles[::7], frames[::7]):
        got = np.array([bundle[f"/convodrive/joint/{n}"] for n in JOINT_NAMES])
        if rotation == "quaternion":
            q = rotations.axis_angle_to_quat(clip.pose[frame])
            want = np.concatenate([q[:, 1:], q[:, :1]], axis=1)
            assert got.shape == (55, 4)
        else:
            want = np.degrees(rotations.axis_angle_to_euler(clip.pose[frame], "YXZ"))
            assert got.shape == (55, 3)
        np.testing.assert_allclose(got, want, atol=1e-4)
        np.testing.assert_allclose(bundle["/convodrive/vad"], clip.vad[frame], atol=1e-6)
        assert bundle["/convodrive/state"] == [int(clip.state[frame])]


def test_vrchat_addresses(tmp_path: Path, talk: Path) -> None:
    listener = UdpListener()
    try:
        done = run_cli(
            "drive", str(talk), "--backend", "osc", "--out", str(tmp_path), "-B", f"osc.port={listener.port}",
            "-B", "osc.face_path=/avatar/parameters/{name}", "-B", "osc.joints=false",
        )  # fmt: skip
    finally:
        bundles = [decode_bundle(d) for d in listener.close()]
    assert done.returncode == 0, done.stderr
    assert set(bundles[0]) == {f"/avatar/parameters/{n}" for n in ARKIT_NAMES} | {
        "/convodrive/vad",
        "/convodrive/state",
    }


def test_a_path_without_a_name_is_one_line(tmp_path: Path, talk: Path) -> None:
    done = run_cli("drive", str(talk), "--backend", "osc", "--out", str(tmp_path), "-B", "osc.face_path=/face")
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "face_path" in done.stderr


@pytest.mark.parametrize("path", ["/x/{name}/{0}", "/x/{name.__class__.__mro__}", "/x/{name}{", "/x/{{name}}"])
def test_a_path_holds_no_field_but_name(tmp_path: Path, talk: Path, path: str) -> None:
    """Paths are not format strings: a positional field, an attribute lookup or a stray brace is
    refused when the options are read, in one line."""
    done = run_cli("drive", str(talk), "--backend", "osc", "--out", str(tmp_path), "-B", f"osc.joint_path={path}")
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "joint_path" in done.stderr and path in done.stderr


def test_a_receiver_that_is_not_there_fails_the_run(tmp_path: Path, talk: Path) -> None:
    """Every bundle to a closed loopback port is refused: the short run reports osc FAILED and,
    osc being its only body, exits 3."""
    done = run_cli("drive", str(talk), "--backend", "osc", "--out", str(tmp_path), "-B", f"osc.port={closed_port()}")
    assert done.returncode == 3, done.stderr
    assert "every backend failed (osc:" in done.stderr.strip().splitlines()[-1]
    report = json.loads((tmp_path / "run_report.json").read_text())
    assert report["every_backend_failed"] is True
    entry = report["backends"]["osc"]
    assert entry["frames_sent"] <= 1 and entry["errors"] >= 30, "each bundle after the first is refused"
    assert "osc        FAILED" in (tmp_path / "run_report.txt").read_text()
