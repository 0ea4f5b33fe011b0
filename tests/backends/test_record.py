"""The record backend, driven directly: files, gap filling, takes, stems, and atomic failure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.backends.base import Session
from convodrive.backends.record import RecordBackend
from convodrive.motion import bvh as bvh_module
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
        m.face[17] = i / 100
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
    assert bvh_module.read_bvh(tmp_path / "motion.bvh").num_frames == 12
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

    def failing(clip):
        for n, line in enumerate(real(clip)):
            if n == 5:
                raise OSError(28, "No space left on device")
            yield line

    monkeypatch.setattr(bvh_module, "_motion_lines", failing)
    backend = RecordBackend()
    backend.open(spec(), Session(out_dir=tmp_path))
    for i in range(20):
        backend.send(frame(i))
    with pytest.raises(OSError, match="motion.bvh"):
        backend.close()
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == ["motion.npz", "motion_livelink.csv", "targets.npz"]  # the others complete, no temp file
    assert backend.report()["errors"] and backend.health()["status"] == "failed"


def test_registered_as_entry_point() -> None:
    assert load_plugin(BACKEND_GROUP, "record") is RecordBackend
    assert RecordBackend.realtime is False
