"""Which node of a user's avatar is which canonical joint, and which morph target is which ARKit
channel.

Bones are found, in order: in a VRM 1.0 file's humanoid map (``VRMC_vrm.humanoid.humanBones``);
by a name map the user gives in a small YAML; by the node's name: SMPL-X names (our own export),
VRM humanoid names (``leftUpperArm``) and the common rig names that ``motion.bvh`` already knows
(``Hips``, ``mixamorig:LeftForeArm``, ``LeftHandIndex1``...). Morph targets match ARKit names
case-insensitively, after any ``prefix.`` (``blendShape1.jawOpen``), or through the YAML map.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from convodrive.motion.bvh_read import canonical_joint_name
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.plumbing.errors import InputFileError
from convodrive.plumbing.safe_yaml import load_yaml_file

_VRM_CENTRE = {
    "hips": "pelvis",
    "spine": "spine1",
    "chest": "spine2",
    "upperChest": "spine3",
    "neck": "neck",
    "head": "head",
    "jaw": "jaw",
}
_VRM_SIDED = {
    "Shoulder": "collar",
    "UpperArm": "shoulder",
    "LowerArm": "elbow",
    "Hand": "wrist",
    "UpperLeg": "hip",
    "LowerLeg": "knee",
    "Foot": "ankle",
    "Toes": "foot",
    "Eye": "eye_smplhf",
    **{f"Thumb{seg}": f"thumb{i}" for i, seg in enumerate(("Metacarpal", "Proximal", "Distal"), 1)},
    **{
        f"{vrm}{seg}": f"{ours}{i}"
        for vrm, ours in (("Index", "index"), ("Middle", "middle"), ("Ring", "ring"), ("Little", "pinky"))
        for i, seg in enumerate(("Proximal", "Intermediate", "Distal"), 1)
    },
}
VRM_TO_CANONICAL: dict[str, str] = {
    **_VRM_CENTRE,
    **{f"{side}{bone}": f"{side}_{ours}" for side in ("left", "right") for bone, ours in _VRM_SIDED.items()},
}
"""VRM 1.0 humanoid bone names to SMPL-X joint names (INTEROP.md)."""
CANONICAL_TO_VRM = {v: k for k, v in VRM_TO_CANONICAL.items()}

REQUIRED_BONES: tuple[str, ...] = (
    "hips",
    "spine",
    "head",
    *(
        f"{side}{bone}"
        for side in ("left", "right")
        for bone in ("UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot")
    ),
)
"""The bones VRM 1.0 requires of every humanoid, by VRM name; without them we cannot drive it."""

_VRM_LOWER = {k.lower(): v for k, v in VRM_TO_CANONICAL.items()}
_ARKIT_LOWER = {n.lower(): n for n in ARKIT_NAMES}


def canonical_for_name(name: str) -> str | None:
    """The canonical joint a node name stands for (SMPL-X, VRM humanoid or common rig names)."""
    if name in JOINT_INDEX:
        return name
    key = re.sub(r"[\s_.\-]", "", name.split(":")[-1]).lower()
    if key in _VRM_LOWER:
        return _VRM_LOWER[key]
    return canonical_joint_name(name)


def arkit_for_name(name: str) -> str | None:
    """The ARKit channel a morph target name stands for: ``jawOpen``, ``JawOpen``,
    ``blendShape1.jawOpen`` and ``ARKit_jawOpen`` all give ``jawOpen``."""
    for candidate in (name, name.rsplit(".", 1)[-1], name.rsplit(":", 1)[-1], name.rsplit("_", 1)[-1]):
        hit = _ARKIT_LOWER.get(candidate.strip().lower())
        if hit:
            return hit
    return None


@dataclasses.dataclass(frozen=True)
class NameMap:
    """A user's map for an avatar whose names we cannot guess: the avatar file it describes,
    canonical joint (SMPL-X or VRM name) -> node name, and ARKit channel -> morph target name."""

    avatar: Path
    bones: dict[str, str]
    morphs: dict[str, str]


def read_name_map(path: Path) -> NameMap:
    """Parse ``avatar: FILE`` (relative to the YAML), ``bones: {hips: Root_Hips, ...}`` and
    ``morphs: {jawOpen: MouthOpen, ...}``; a mistake is one line naming the file and the key."""
    data: Any = load_yaml_file(path)
    if not isinstance(data, Mapping):
        raise InputFileError(path, "expected a mapping with 'avatar', 'bones' and 'morphs'")
    unknown = set(data) - {"avatar", "bones", "morphs"}
    if unknown:
        raise InputFileError(
            path, f"unknown key(s) {', '.join(sorted(map(str, unknown)))} (known: avatar, bones, morphs)"
        )
    if not isinstance(data.get("avatar"), str):
        raise InputFileError(path, "'avatar' must name the .glb, .gltf or .vrm file the map is for")
    bones: dict[str, str] = {}
    for key, node in _string_map(path, data, "bones").items():
        canonical = key if key in JOINT_INDEX else VRM_TO_CANONICAL.get(key)
        if canonical is None:
            raise InputFileError(path, f"bones: {key!r} is neither a VRM humanoid bone nor an SMPL-X joint name")
        bones[canonical] = node
    morphs = _string_map(path, data, "morphs")
    for key in morphs:
        if key not in ARKIT_NAMES:
            raise InputFileError(path, f"morphs: {key!r} is not an ARKit blendshape name")
    return NameMap((path.parent / data["avatar"]).resolve(), bones, morphs)


def _string_map(path: Path, data: Mapping[str, Any], key: str) -> dict[str, str]:
    value = data.get(key) or {}
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        raise InputFileError(path, f"'{key}' must map names to names")
    return dict(value)
