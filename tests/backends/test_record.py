"""The record backend, driven directly: files, gap filling, takes, stems, and atomic failure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.backends.base import Session
from convodrive.backends.record import RecordBackend
from convodrive.motion import bvh as bvh_module
from convodrive.motion import rotations
from convodrive.motion.bvh_read import read_bvh
from convodrive.motion.clip import MotionFrame
from convodrive.motion.npz import load_clip
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins import BACKEND_GROUP, load_plugin
from convodrive.plumbing.errors import UserError


def spec() -> TargetSpec:
    n = 2
    return TargetSpec(
        "head",
        ("yaw", "pitch"),
        -np.ones(n),
        np.ones(n),
        np.zeros(n),
        np.full(n, np.inf),
        np.full(n, np.inf),
        ("rad", "rad"),
    )


def frame(i: int, takes: int = 1) -> TargetFrame:
    motions = []
    for k in range(takes):
        m = MotionFrame.neutral(i / 30)
        m.pose[15] = [0.01 * i, 0.0, 0.1 * k]
        m.face[17] = (i % 100) / 100
        m.translation[0] = i / 1000
        motions.append(m)
    return TargetFrame(i, i / 30, np.array([i / 100, -i / 100]), tuple(motions))


def run(tmp_path: Path, indices, num_frames=None, takes=1, options=None, target_spec=None) -> RecordBackend:
    backend = RecordBackend(options)
    backend.open(target_spec or spec(), Session(out_dir=tmp_path, num_frames=num_frames, num_samples=takes))
    for i in indices:
        backend.send(frame(i, takes))
    backend.close()
    return backend


def test_writes_every_output(tmp_path: Path) -> None:
    backend = run(tmp_path, range(12))
    names = sorted(p.name for p in backend.outputs())
    assert names == ["motion.bvh", "motion.npz", "motion_livelink.csv", "targets.npz"]
    assert sorted(p.name for p in tmp_path.iterdir()) == names  # and nothing else, no temp files
    clip = load_clip(tmp_path / "motion.npz")
    assert clip.num_frames == 12 and clip.fps == 30
    np.testing.assert_allclose(clip.pose[:, 15, 0], np.arange(12) * 0.01, atol=1e-6)
    with np.load(tmp_path / "targets.npz") as t:
        assert list(t["names"]) == ["yaw", "pitch"]
        np.testing.assert_allclose(t["values"][:, 0], np.arange(12) / 100, atol=1e-6)
        np.testing.assert_allclose(t["time"], np.arange(12) / 30)
    assert read_bvh(tmp_path / "motion.bvh").num_frames == 12
    assert len((tmp_path / "motion_livelink.csv").read_text().splitlines()) == 13
    assert backend.report()["frames_received"] == 12 and backend.report()["frames_filled"] == 0


def test_dropped_frames_hold_the_previous_and_are_counted(tmp_path: Path) -> None:
    received = [0, 1, 2, 3, 6, 7]  # 4 and 5 dropped; the run stopped after 7 (say, Ctrl-C)
    backend = run(tmp_path, received, num_frames=10)
    clip = load_clip(tmp_path / "motion.npz")
    assert clip.num_frames == 8, "a run that stopped early is not padded to the audio's length"
    expected_source = [0, 1, 2, 3, 3, 3, 6, 7]
    np.testing.assert_allclose(clip.pose[:, 15, 0], np.array(expected_source) * 0.01, atol=1e-6)
    with np.load(tmp_path / "targets.npz") as t:
        np.testing.assert_allclose(t["values"][:, 0], np.array(expected_source) / 100, atol=1e-6)
    report = backend.report()
    assert report["frames_received"] == 6 and report["frames_filled"] == 2 and report["frames_written"] == 8


def test_takes_stem_and_canonical_only_spec(tmp_path: Path) -> None:
    run(tmp_path, range(5), takes=3, options={"stem": "chat"}, target_spec=TargetSpec.empty())
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "chat.bvh",
        "chat.npz",
        "chat_livelink.csv",
        "chat_take1.npz",
        "chat_take2.npz",
    ]
    for k, name in enumerate(["chat.npz", "chat_take1.npz", "chat_take2.npz"]):
        np.testing.assert_allclose(load_clip(tmp_path / name).pose[:, 15, 2], 0.1 * k, atol=1e-6)


def test_bad_stem_is_a_user_error() -> None:
    with pytest.raises(UserError, match="stem"):
        RecordBackend({"stem": "../escape"})


def test_failed_write_leaves_no_partial_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = bvh_module._motion_lines

    def failing(*args):
        for n, line in enumerate(real(*args)):
            if n == 5:
                raise OSError(28, "No space left on device")
            yield line

    monkeypatch.setattr(bvh_module, "_motion_lines", failing)
    backend = RecordBackend()
    backend.open(spec(), Session(out_dir=tmp_path))
    for i in range(20):
        backend.send(frame(i))
    with pytest.raises(OSError, match="motion.bvh: OSError: .*No space left on device"):
        backend.close()
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == ["motion.npz", "motion_livelink.csv", "targets.npz"]  # the others complete, no temp file
    assert backend.report()["errors"] and backend.health()["status"] == "failed"


def test_registered_as_entry_point() -> None:
    assert load_plugin(BACKEND_GROUP, "record") is RecordBackend
    assert RecordBackend.realtime is False


def test_frames_go_to_disk_as_they_arrive(tmp_path: Path) -> None:
    backend = RecordBackend()
    backend.open(spec(), Session(out_dir=tmp_path, num_samples=2))
    for i in range(500):
        backend.send(frame(i, takes=2))
    spools = list(tmp_path.glob(".motion.spool-*"))
    assert len(spools) == 1, "one spool folder beside the outputs while the run goes on"
    pose_bytes = sum(f.stat().st_size for f in spools[0].glob("take*/pose.raw"))
    assert pose_bytes >= 2 * 500 * 55 * 3 * 4 - 2 * 8192, "the frames are on disk, not held in memory"
    backend.close()
    assert not list(tmp_path.glob(".*")), "the spool is gone once the files are written"
    clip = load_clip(tmp_path / "motion.npz")
    np.testing.assert_allclose(clip.pose[:, 15, 0], np.arange(500) * 0.01, atol=1e-6)
    np.testing.assert_allclose(load_clip(tmp_path / "motion_take1.npz").pose[:, 15, 2], 0.1, atol=1e-6)


def test_long_recordings_are_valid_in_every_format(tmp_path: Path) -> None:
    from convodrive.motion.livelink import read_livelink_csv

    n = 3000  # several of the writers' blocks, with a gap to fill in the middle
    received = [i for i in range(n) if not 1500 <= i < 1510]
    backend = run(tmp_path, received)
    clip = load_clip(tmp_path / "motion.npz")
    assert clip.num_frames == n and backend.report()["frames_filled"] == 10
    source = np.array([i if not 1500 <= i < 1510 else 1499 for i in range(n)])
    np.testing.assert_allclose(clip.pose[:, 15, 0], source * 0.01, atol=1e-6)
    np.testing.assert_allclose(clip.face[:, 17], (source % 100) / 100, atol=1e-6)
    bvh = read_bvh(tmp_path / "motion.bvh")
    as_matrix = rotations.axis_angle_to_matrix  # the angle grows past pi: compare rotations, not vectors
    np.testing.assert_allclose(as_matrix(bvh.pose[:, 15]), as_matrix(clip.pose[:, 15]), atol=1e-4)
    np.testing.assert_allclose(bvh.translation, clip.translation, atol=1e-5)
    face = read_livelink_csv(tmp_path / "motion_livelink.csv")
    np.testing.assert_allclose(face.face, clip.face, atol=1e-6)
    with np.load(tmp_path / "targets.npz") as t:
        np.testing.assert_allclose(t["values"][:, 1], -source / 100, atol=1e-6)
        np.testing.assert_allclose(t["time"], np.arange(n) / 30)


def test_a_spool_left_by_a_killed_run_is_swept(tmp_path: Path) -> None:
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".motion.spool-{dead.stdout.strip()}-abcd"
    (stale / "take0").mkdir(parents=True)
    (stale / "take0" / "pose.raw").write_bytes(b"\0" * 660)
    run(tmp_path, range(3))
    assert not stale.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "motion.bvh",
        "motion.npz",
        "motion_livelink.csv",
        "targets.npz",
    ]
