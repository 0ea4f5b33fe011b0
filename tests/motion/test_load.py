"""The one motion loader: .npz, BVH and Live Link CSV by suffix; every problem one line naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.motion.bvh import write_bvh
from convodrive.motion.clip import MotionClip
from convodrive.motion.livelink import write_livelink_csv
from convodrive.motion.load import absent_parts, load_motion
from convodrive.motion.npz import save_clip
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.plumbing.errors import InputFileError


def talking_clip(num_frames: int = 12) -> MotionClip:
    clip = MotionClip.neutral(num_frames)
    clip.pose[:, JOINT_INDEX["head"], 1] = np.linspace(0, 0.3, num_frames)
    clip.pose[:, JOINT_INDEX["left_elbow"], 1] = 0.4
    clip.face[:, 17] = np.linspace(0, 1, num_frames)
    return clip


def test_each_format_by_its_suffix(tmp_path: Path) -> None:
    clip = talking_clip()
    npz = load_motion(save_clip(clip, tmp_path / "a.npz"))
    bvh = load_motion(write_bvh(clip, tmp_path / "a.BVH"))
    csv = load_motion(write_livelink_csv(clip, tmp_path / "a.csv"))
    for loaded in (npz, bvh, csv):
        assert loaded.num_frames == 12 and loaded.fps == 30
        np.testing.assert_allclose(
            loaded.pose[:, JOINT_INDEX["head"], 1], clip.pose[:, JOINT_INDEX["head"], 1], atol=1e-5
        )
    assert bvh.metadata["format"] == "bvh" and csv.metadata["format"] == "livelink"
    np.testing.assert_allclose(npz.face, clip.face)
    np.testing.assert_allclose(csv.face, clip.face, atol=1e-6)


def test_what_each_format_leaves_out(tmp_path: Path) -> None:
    clip = talking_clip()
    assert absent_parts(load_motion(save_clip(clip, tmp_path / "a.npz"))) == []
    assert absent_parts(load_motion(write_bvh(clip, tmp_path / "a.bvh"))) == ["face (every blendshape channel is 0)"]
    assert absent_parts(load_motion(write_livelink_csv(clip, tmp_path / "a.csv"))) == [
        "body (every joint below the head is at rest)"
    ]


@pytest.mark.parametrize(
    "name, needle",
    [
        ("notes.txt", "unsupported motion format '.txt'"),
        ("noext", "unsupported motion format '(none)'"),
        ("absent.npz", "no such file"),
        ("folder.bvh", "is a folder"),
        ("empty.npz", "holds no frames"),
        ("garbage.csv", "not a Live Link Face CSV"),
    ],
)
def test_problems_are_one_line_naming_the_file(tmp_path: Path, name: str, needle: str) -> None:
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "noext").write_text("hello")
    (tmp_path / "folder.bvh").mkdir()
    (tmp_path / "garbage.csv").write_text("a,b\n1,2\n")
    save_clip(MotionClip.neutral(0), tmp_path / "empty.npz")
    with pytest.raises(InputFileError) as err:
        load_motion(tmp_path / name)
    message = str(err.value)
    assert message.startswith(str(tmp_path / name)) and needle in message and "\n" not in message
