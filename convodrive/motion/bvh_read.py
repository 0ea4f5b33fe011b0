"""BVH import: any BVH, ours, or a third party's with other joint names, channel orders and
units. Joints map to the canonical skeleton by name (exact SMPL-X names first, then a small alias
table of common names such as ``Hips``, ``LeftArm``, ``mixamorig:LeftForeArm``); unmapped joints
are ignored and missing joints stay at rest. Limitation: a third party's local rotations are taken
as they are, so a file whose rest pose is not a T-pose like ours (an A-pose, another up axis, bones
along other axes) comes in with that difference baked into its poses; no re-posing is attempted.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from convodrive.motion import rotations
from convodrive.motion.bvh import POS_CHANNELS
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import (
    JOINT_INDEX,
    NUM_JOINTS,
    REST_POSITIONS,
)
from convodrive.plumbing.errors import InputFileError

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


_VALID_CHANNELS = set(POS_CHANNELS) | {f"{a}rotation" for a in "XYZ"}


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
    if all(c in root.channels for c in POS_CHANNELS):
        position_cols = [root.first_channel + root.channels.index(c) for c in POS_CHANNELS]
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
