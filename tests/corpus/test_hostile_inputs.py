"""Hostile source files for the importers: pickles whose shared references or nesting explode when
walked, ``.npy`` headers claiming shapes their entries do not hold, clips with no frames, poses of
the wrong kind and empty frame rates. Each is one line naming the file, exit 2, nothing written,
in bounded time and memory."""

from __future__ import annotations

import io
import pickle
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.conftest import REPO
from tests.corpus.test_importers import fails

WAV = REPO / "samples" / "dialogue.wav"


def show_clip(src: Path, raw: bytes) -> Path:
    """A SHOW layout holding one clip whose pickle is ``raw``."""
    where = src / "a" / "v" / "c"
    where.mkdir(parents=True)
    (where / "c.pkl").write_bytes(raw)
    shutil.copy(WAV, where / "c.wav")
    return where / "c.pkl"


def shared(levels: int) -> list[Any]:
    """A list of ``levels`` levels, each holding the one below twice: 2**levels paths, a few
    hundred bytes pickled."""
    x: Any = "leaf"
    for _ in range(levels):
        x = [x, x]
    return x


def self_holding() -> list[Any]:
    x: list[Any] = []
    x.append(x)
    return x


@pytest.mark.parametrize(
    ("raw", "problem"),
    [
        (pickle.dumps({"n": shared(60)}), "containers nested deeper than 32"),
        (pickle.dumps({"n": shared(25)}), "more than 1000000 items once shared references are expanded"),
        (pickle.dumps({"n": self_holding()}), "a container holds itself"),
        (b"(" * 100000 + b"l" * 100000 + b".", "containers nested deeper than 32"),
    ],
    ids=["shared-60", "shared-25", "self", "deep"],
)
def test_show_pickles_that_explode_when_walked_are_refused(tmp_path: Path, raw: bytes, problem: str) -> None:
    assert len(raw) <= 200_001  # a small file
    pkl = show_clip(tmp_path / "show", raw)
    fails("show", tmp_path / "show", tmp_path / "out", str(pkl), f"refused: {problem}")


@pytest.mark.parametrize("bad", ["abcdef", [{"x": 1.0}] * 10], ids=["string", "dicts"])
def test_show_poses_that_are_not_numbers_are_one_line(tmp_path: Path, bad: Any) -> None:
    pkl = show_clip(tmp_path / "show", pickle.dumps({"body_pose_axis": bad}))
    fails("show", tmp_path / "show", tmp_path / "out", str(pkl), "'body_pose_axis' is not an array of numbers")


def beat2_clip(src: Path) -> Path:
    (src / "smplxflame_30").mkdir(parents=True)
    (src / "wave16k").mkdir()
    shutil.copy(WAV, src / "wave16k" / "1_x_0.wav")
    return src / "smplxflame_30" / "1_x_0.npz"


def test_beat2_npy_header_claiming_a_huge_shape_is_refused_unread(tmp_path: Path) -> None:
    npz = beat2_clip(tmp_path / "b")
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f4", "fortran_order": False, "shape": (10**12, 165)}
    )  # 660 TB claimed, 6.6 kB held
    with zipfile.ZipFile(npz, "w") as zf:
        zf.writestr("poses.npy", header.getvalue() + np.zeros((10, 165), np.float32).tobytes())
    fails("beat2", tmp_path / "b", tmp_path / "out", str(npz), "'poses' claims shape (1000000000000, 165)")


def test_beat2_clip_with_no_frames_is_one_line(tmp_path: Path) -> None:
    npz = beat2_clip(tmp_path / "b")
    np.savez(npz, poses=np.zeros((0, 165)), trans=np.zeros((0, 3)))
    fails("beat2", tmp_path / "b", tmp_path / "out", str(npz), "holds no frames")


@pytest.mark.parametrize("fps", [np.zeros(0), np.zeros((2, 2))], ids=["empty", "matrix"])
def test_seamless_frame_rate_that_is_not_one_number_is_one_line(tmp_path: Path, fps: np.ndarray) -> None:
    src = tmp_path / "s"
    src.mkdir()
    npz = src / "V00_S0_I0_P1.npz"
    np.savez(npz, **{"smplh:fps": fps, "smplh:poses": np.zeros((30, 156))})
    shutil.copy(WAV, npz.with_suffix(".wav"))
    fails("seamless", src, tmp_path / "out", str(npz), "frame rate has shape")
