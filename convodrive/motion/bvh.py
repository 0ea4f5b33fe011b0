"""BVH export and import, so that Blender, Unity and MotionBuilder can use convodrive's motion.

Our files are in **centimetres** (what Blender's and Unity's importers expect by default), Y up,
facing +Z, with the canonical 55-joint skeleton in T-pose as the rest pose. The root has six
channels, ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``; every other joint has
the three rotation channels in that same order, which means R = Rz @ Rx @ Ry (intrinsic Z, X, Y,
as ``convodrive.motion.rotations`` reads the order string ``"ZXY"``). Rotations are in degrees.
The root's OFFSET is its rest position and its position channels are absolute, as Blender reads them.

``read_bvh`` imports any BVH: ours, or a third party's with other joint names, channel orders and
units. Joints map to the canonical skeleton by name (exact SMPL-X names first, then a small alias
table of common names such as ``Hips``, ``LeftArm``, ``mixamorig:LeftForeArm``); unmapped joints
are ignored and missing joints stay at rest. Limitation: a third party's local rotations are taken
as they are, so a file whose rest pose is not a T-pose like ours (an A-pose, another up axis, bones
along other axes) comes in with that difference baked into its poses; no re-posing is attempted.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from convodrive.motion import rotations
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import (
    JOINT_INDEX,
    JOINT_NAMES,
    NUM_JOINTS,
    PARENTS,
    REST_OFFSETS,
    REST_POSITIONS,
    children,
)
from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.errors import InputFileError

UNITS_PER_METRE = 100.0
"""Our BVH files are in centimetres."""
EULER_ORDER = "ZXY"
FRAME_TIME = "0.0333333"
_BLOCK = 1024
_ROT_CHANNELS = [f"{axis}rotation" for axis in EULER_ORDER]
_POS_CHANNELS = ["Xposition", "Yposition", "Zposition"]

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
        channels = (_POS_CHANNELS if PARENTS[j] < 0 else []) + _ROT_CHANNELS
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


# ---------------------------------------------------------------- import

_SIDES = {"left": "left", "l": "left", "right": "right", "r": "right"}
_SIDED_ALIASES = {
    "shoulder": "collar",
    "clavicle": "collar",
    "collar": "collar",
    "arm": "shoulder",
    "upperarm": "shoulder",
    "forearm": "elbow",
    "lowerarm": "elbow",
    "elbow": "elbow",
    "hand": "wrist",
    "wrist": "wrist",
    "upleg": "hip",
    "upperleg": "hip",
    "thigh": "hip",
    "hip": "hip",
    "leg": "knee",
    "lowerleg": "knee",
    "shin": "knee",
    "knee": "knee",
    "calf": "knee",
    "foot": "ankle",
    "ankle": "ankle",
    "toebase": "foot",
    "toe": "foot",
    "toes": "foot",
    "eye": "eye_smplhf",
}
_CENTRE_ALIASES = {
    "hips": "pelvis",
    "pelvis": "pelvis",
    "root": "pelvis",
    "spine": "spine1",
    "spine1": "spine2",
    "spine2": "spine3",
    "chest": "spine2",
    "upperchest": "spine3",
    "neck": "neck",
    "head": "head",
    "jaw": "jaw",
}
_FINGERS = ("thumb", "index", "middle", "ring", "pinky")


def canonical_joint_name(name: str) -> str | None:
    """The canonical joint a BVH joint name stands for, or None.

    Exact SMPL-X names win; then common names, case-insensitive, with a namespace prefix
    (``mixamorig:``) and separators removed: ``Hips``, ``Spine``/``Spine1``/``Spine2`` (Mixamo's
    three spine joints), ``Neck``, ``Head``, ``LeftShoulder`` (the collar), ``LeftArm``,
    ``LeftForeArm``, ``LeftHand``, ``LeftUpLeg``, ``LeftLeg``, ``LeftFoot``, ``LeftToeBase``,
    ``LeftHandIndex1``..3 and the other fingers (``Pinky`` or ``Little``).
    """
    if name in JOINT_INDEX:
        return name
    key = re.sub(r"[\s_.\-]", "", name.split(":")[-1]).lower()
    if key in _CENTRE_ALIASES:
        return _CENTRE_ALIASES[key]
    for pattern, side_group in ((r"(left|right|l|r)(.+)", 1), (r"(.+?)(left|right|l|r)", 2)):
        m = re.fullmatch(pattern, key)
        if not m:
            continue
        side, part = _SIDES[m.group(side_group)], m.group(3 - side_group)
        finger = re.fullmatch(r"(?:hand)?(thumb|index|middle|ring|pinky|little)([123])", part)
        if finger:
            digit = "pinky" if finger.group(1) == "little" else finger.group(1)
            return f"{side}_{digit}{finger.group(2)}"
        if part in _SIDED_ALIASES:
            return f"{side}_{_SIDED_ALIASES[part]}"
    return None


class _Joint:
    def __init__(self, name: str, parent: _Joint | None, line: int) -> None:
        self.name, self.parent, self.line = name, parent, line
        self.offset = np.zeros(3)
        self.channels: list[str] = []
        self.first_channel = 0


_VALID_CHANNELS = set(_POS_CHANNELS) | {f"{a}rotation" for a in "XYZ"}


def _parse_hierarchy(path: Path, lines: list[str]) -> tuple[list[_Joint], int]:
    """Parse up to MOTION; return the joints (file order) and the index of the MOTION line."""
    joints: list[_Joint] = []
    stack: list[_Joint | None] = []  # None marks an End Site block
    pending: _Joint | None = None
    in_end_site = False
    n_channels = 0
    i = 0
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines) or lines[i].split()[0].upper() != "HIERARCHY":
        raise InputFileError(path, f"line {i + 1}: not a BVH file (expected 'HIERARCHY')")
    first = i + 1
    for i in range(first, len(lines)):
        words = lines[i].split()
        if not words:
            continue
        key = words[0].upper()
        where = f"line {i + 1}"
        if key in ("ROOT", "JOINT"):
            if (key == "ROOT") != (not stack):
                raise InputFileError(path, f"{where}: {words[0]} is not allowed here")
            if len(words) < 2:
                raise InputFileError(path, f"{where}: {words[0]} needs a name")
            parent = stack[-1] if stack else None
            pending = _Joint(" ".join(words[1:]), parent, i + 1)
            joints.append(pending)
        elif key == "END":
            if not stack or stack[-1] is None:
                raise InputFileError(path, f"{where}: End Site outside a joint")
            in_end_site = True
        elif key == "{":
            if in_end_site:
                stack.append(None)
                in_end_site = False
            elif pending is not None:
                stack.append(pending)
                pending = None
            else:
                raise InputFileError(path, f"{where}: unexpected '{{'")
        elif key == "}":
            if not stack:
                raise InputFileError(path, f"{where}: unbalanced '}}'")
            stack.pop()
        elif key == "OFFSET":
            if not stack:
                raise InputFileError(path, f"{where}: OFFSET outside a joint")
            try:
                offset = np.array([float(w) for w in words[1:4]])
            except ValueError:
                raise InputFileError(path, f"{where}: OFFSET needs three numbers") from None
            if offset.shape != (3,) or not np.all(np.isfinite(offset)):
                raise InputFileError(path, f"{where}: OFFSET needs three finite numbers")
            if stack[-1] is not None:
                stack[-1].offset = offset
        elif key == "CHANNELS":
            if not stack or stack[-1] is None:
                raise InputFileError(path, f"{where}: CHANNELS outside a joint")
            try:
                count = int(words[1])
            except (IndexError, ValueError):
                raise InputFileError(path, f"{where}: CHANNELS needs a count") from None
            names = words[2:]
            if len(names) != count or any(n not in _VALID_CHANNELS for n in names):
                raise InputFileError(path, f"{where}: CHANNELS {count} must list {count} of Xposition..Zrotation")
            stack[-1].channels = names
            stack[-1].first_channel = n_channels
            n_channels += count
        elif key == "MOTION":
            if stack or pending is not None or not joints:
                raise InputFileError(path, f"{where}: MOTION before the hierarchy is complete")
            return joints, i
        else:
            raise InputFileError(path, f"{where}: unexpected '{words[0]}' in the hierarchy")
    raise InputFileError(path, "no MOTION section")


def _parse_motion(path: Path, lines: list[str], start: int, n_channels: int) -> tuple[np.ndarray, float]:
    header: dict[str, str] = {}
    i = start + 1
    for label in ("frames:", "frame time:"):
        while i < len(lines) and not lines[i].strip():
            i += 1
        line = lines[i].strip() if i < len(lines) else ""
        if not line.lower().startswith(label):
            raise InputFileError(path, f"line {i + 1}: expected '{label.capitalize()}'")
        header[label] = line[len(label) :].strip()
        i += 1
    try:
        num_frames = int(header["frames:"])
        frame_time = float(header["frame time:"])
    except ValueError:
        raise InputFileError(path, f"line {start + 2}: Frames / Frame Time are not numbers") from None
    if num_frames < 0 or not frame_time > 0:
        raise InputFileError(path, f"line {start + 2}: Frames must be >= 0 and Frame Time > 0")
    rows = [(n + 1, line) for n, line in enumerate(lines[i:], start=i) if line.strip()]
    if len(rows) < num_frames:
        raise InputFileError(path, f"declares {num_frames} frames but holds {len(rows)}")
    data = np.empty((num_frames, n_channels))
    for k, (lineno, line) in enumerate(rows[:num_frames]):
        try:
            values = np.array(line.split(), dtype=np.float64)
        except ValueError:
            raise InputFileError(path, f"line {lineno}: frame {k} holds a value that is not a number") from None
        if len(values) != n_channels:
            raise InputFileError(
                path, f"line {lineno}: frame {k} has {len(values)} values, the hierarchy declares {n_channels}"
            )
        if not np.all(np.isfinite(values)):
            raise InputFileError(path, f"line {lineno}: frame {k} holds NaN or infinite values")
        data[k] = values
    return data, frame_time


def _metres_per_unit(joints: list[_Joint]) -> float:
    """Guess the file's unit from its rest skeleton: more than 10 units across means centimetres."""
    positions: dict[int, np.ndarray] = {}
    for j in joints:  # parents come before their children in file order
        positions[id(j)] = (positions[id(j.parent)] if j.parent is not None else 0.0) + j.offset
    extent = float(np.ptp(np.array(list(positions.values())), axis=0).max())
    return 0.01 if extent > 10.0 else 1.0


def _nice_fps(frame_time: float) -> float:
    """``Frame Time: 0.0333333`` means 30 fps, not 30.0003."""
    fps = 1.0 / frame_time
    return float(round(fps)) if abs(fps - round(fps)) < 1e-3 * fps else fps


def read_bvh(path: str | os.PathLike[str]) -> MotionClip:
    """Import a BVH file as a clip (local axis-angle rotations; see the module notes)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such file")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        raise InputFileError(path, "not a BVH file (not text)") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({exc.strerror})") from None
    lines = text.splitlines()
    joints, motion_line = _parse_hierarchy(path, lines)
    n_channels = sum(len(j.channels) for j in joints)
    data, frame_time = _parse_motion(path, lines, motion_line, n_channels)
    scale = _metres_per_unit(joints)

    num_frames = len(data)
    pose = np.zeros((num_frames, NUM_JOINTS, 3))
    translation = np.zeros((num_frames, 3))
    mapped: dict[str, str] = {}
    for j in joints:
        target = canonical_joint_name(j.name)
        if target is None or target in mapped.values():
            continue
        mapped[j.name] = target
        cols = {c: j.first_channel + k for k, c in enumerate(j.channels)}
        rot = [c for c in j.channels if c.endswith("rotation")]
        if len(rot) == 3:
            angles = np.radians(data[:, [cols[c] for c in rot]])
            pose[:, JOINT_INDEX[target]] = rotations.euler_to_axis_angle(angles, "".join(c[0] for c in rot))
        elif rot:
            raise InputFileError(
                path, f"line {j.line}: joint {j.name} has {len(rot)} rotation channels (BVH needs 3 or none)"
            )
    root = joints[0]
    if all(c in root.channels for c in _POS_CHANNELS):
        position_cols = [root.first_channel + root.channels.index(c) for c in _POS_CHANNELS]
        translation = data[:, position_cols] * scale - REST_POSITIONS[0]
    if not mapped:
        raise InputFileError(path, "no joint matches the canonical skeleton by name (e.g. pelvis/Hips, head/Head)")
    return MotionClip(
        pose=pose.astype(np.float32),
        translation=translation.astype(np.float32),
        face=np.zeros((num_frames, 52), np.float32),
        vad=np.zeros((num_frames, 2), np.float32),
        state=np.zeros(num_frames, np.int8),
        fps=_nice_fps(frame_time),
        metadata={"source": str(path), "format": "bvh", "mapped_joints": mapped},
    )
