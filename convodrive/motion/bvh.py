"""BVH export, so that Blender, Unity and MotionBuilder can use convodrive's motion.

Our files are in **centimetres** (what Blender's and Unity's importers expect by default), Y up,
facing +Z, with the canonical 55-joint skeleton in T-pose as the rest pose. The root has six
channels, ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``; every other joint has
the three rotation channels in that same order, which means R = Rz @ Rx @ Ry (intrinsic Z, X, Y,
as ``convodrive.motion.rotations`` reads the order string ``"ZXY"``). Rotations are in degrees.
The root's OFFSET is its rest position and its position channels are absolute, as Blender reads them.

``bvh_read.read_bvh`` imports any BVH, ours or a third party's.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from convodrive.motion import rotations
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import (
    JOINT_NAMES,
    PARENTS,
    REST_OFFSETS,
    REST_POSITIONS,
    children,
)
from convodrive.plumbing.atomic import atomic_path

UNITS_PER_METRE = 100.0
"""Our BVH files are in centimetres."""
EULER_ORDER = "ZXY"
FRAME_TIME = "0.0333333"
_BLOCK = 1024
_ROT_CHANNELS = [f"{axis}rotation" for axis in EULER_ORDER]
POS_CHANNELS = ["Xposition", "Yposition", "Zposition"]

# End Sites (metres, in the leaf joint's frame) give the leaves a visible length in viewers.
_END_SITES = {"foot": (0.0, 0.0, 0.06), "jaw": (0.0, -0.03, 0.07), "eye": (0.0, 0.0, 0.02)}


def _end_site(joint: int) -> np.ndarray:
    name = JOINT_NAMES[joint]
    for key, offset in _END_SITES.items():
        if key in name:
            return np.array(offset)
    return 0.8 * REST_OFFSETS[joint]  # fingertips continue the last phalanx


def _depth_first() -> list[int]:
    order: list[int] = []

    def visit(j: int) -> None:
        order.append(j)
        for c in children(j):
            visit(c)

    visit(0)
    return order


_DFS = _depth_first()


def _fmt(values: np.ndarray) -> str:
    return " ".join(f"{v:.6f}" for v in values)


def _hierarchy_lines() -> Iterator[str]:
    yield "HIERARCHY"

    def joint(j: int, depth: int) -> Iterator[str]:
        pad = "\t" * depth
        kind = "ROOT" if PARENTS[j] < 0 else "JOINT"
        yield f"{pad}{kind} {JOINT_NAMES[j]}"
        yield f"{pad}{{"
        yield f"{pad}\tOFFSET {_fmt(REST_OFFSETS[j] * UNITS_PER_METRE)}"
        channels = (POS_CHANNELS if PARENTS[j] < 0 else []) + _ROT_CHANNELS
        yield f"{pad}\tCHANNELS {len(channels)} {' '.join(channels)}"
        kids = children(j)
        for c in kids:
            yield from joint(c, depth + 1)
        if not kids:
            yield f"{pad}\tEnd Site"
            yield f"{pad}\t{{"
            yield f"{pad}\t\tOFFSET {_fmt(_end_site(j) * UNITS_PER_METRE)}"
            yield f"{pad}\t}}"
        yield f"{pad}}}"

    yield from joint(0, 0)


def _motion_lines(num_frames: int, fps: float, blocks: Iterable[tuple[np.ndarray, np.ndarray]]) -> Iterator[str]:
    """The MOTION section from (pose, translation) blocks of consecutive frames."""
    yield "MOTION"
    yield f"Frames: {num_frames}"
    yield f"Frame Time: {FRAME_TIME if abs(fps - 30) < 1e-9 else f'{1.0 / fps:.7f}'}"
    row_format = " ".join(["%.6f"] * (3 + 3 * len(_DFS)))  # printf-style: twice as fast as f-strings
    for pose, translation in blocks:
        euler = np.degrees(rotations.axis_angle_to_euler(pose[:, _DFS], EULER_ORDER))
        position = (REST_POSITIONS[0] + translation) * UNITS_PER_METRE
        for row in np.concatenate([position, euler.reshape(len(euler), -1)], axis=1).tolist():
            yield row_format % tuple(row)


def _clip_blocks(clip: MotionClip, block: int = _BLOCK) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(pose, translation) of ``clip`` in blocks: hours of motion in bounded memory."""
    for start in range(0, clip.num_frames, block):
        yield clip.pose[start : start + block], clip.translation[start : start + block]


def write_bvh(clip: MotionClip, path: str | os.PathLike[str]) -> Path:
    """Write ``clip`` as a BVH file (atomically); face and voice activity are not part of BVH."""
    return write_bvh_blocks(path, clip.num_frames, clip.fps, _clip_blocks(clip))


def write_bvh_blocks(
    path: str | os.PathLike[str], num_frames: int, fps: float, blocks: Iterable[tuple[np.ndarray, np.ndarray]]
) -> Path:
    """Write ``num_frames`` frames given as (pose (n, 55, 3), translation (n, 3)) blocks, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            for line in _hierarchy_lines():
                fh.write(line + "\n")
            for line in _motion_lines(num_frames, fps, blocks):
                fh.write(line + "\n")
    return path
