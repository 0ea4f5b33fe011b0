"""Surfaces read from a glTF's primitives assembled into one ``Rig``: vertices concatenated,
normals made where the file has none, morph deltas packed onto the vertices they move, and the
landmarks cameras frame by (saved by our own files, measured on the head for others).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from convodrive.backends.avatar.rig import Material, Rig, Skeleton, Surface
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.skeleton import JOINT_NAMES


class Parts:
    """Surfaces gathered from the file's primitives, concatenated into one rig."""

    def __init__(self) -> None:
        self.surfaces: list[
            tuple[
                Material,
                np.ndarray,
                np.ndarray | None,
                np.ndarray,
                np.ndarray | None,
                np.ndarray,
                sp.csr_matrix,
                dict[str, np.ndarray],
            ]
        ] = []

    def add(self, material, pos, normals, colors, uv, faces, weights, deltas) -> None:  # type: ignore[no-untyped-def]
        self.surfaces.append((material, pos, normals, colors, uv, faces, weights, deltas))

    def to_rig(self, name: str, doc: dict[str, Any], skeleton: Skeleton) -> Rig:
        from convodrive.backends.avatar.skinning import smooth_normals

        materials, surfaces, normals, weights = [], [], [], []
        offset = 0
        for material, pos, nrm, _, _, faces, w, _ in self.surfaces:
            materials.append(material)
            surfaces.append(Surface(len(materials) - 1, offset, offset + len(pos), faces.astype(np.uint32)))
            if nrm is None:
                nrm = smooth_normals(pos, faces)
            normals.append(nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12))
            w = w.tocsr()
            w.resize((len(pos), skeleton.num_joints))
            weights.append(w)
            offset += len(pos)
        rest = np.concatenate([s[1] for s in self.surfaces])
        present = {name for s in self.surfaces for name in s[7]}
        names = tuple(n for n in ARKIT_NAMES if n in present)
        full = np.zeros((len(names), len(rest), 3))
        for k, name in enumerate(names):
            full[k] = np.concatenate([s[7].get(name, np.zeros((len(s[1]), 3))) for s in self.surfaces])
        index = np.flatnonzero(np.abs(full).max(axis=(0, 2)) > 0) if names else np.zeros(0, np.int64)
        any_uv = any(s[4] is not None for s in self.surfaces)
        rig = Rig(
            name=name,
            rest=rest.astype(np.float32),
            normals=np.concatenate(normals).astype(np.float32),
            colors=np.concatenate([s[3] for s in self.surfaces]).astype(np.float32),
            uv=np.concatenate([s[4] if s[4] is not None else np.zeros((len(s[1]), 2)) for s in self.surfaces]).astype(
                np.float32
            )
            if any_uv
            else None,
            surfaces=surfaces,
            materials=materials,
            skeleton=skeleton,
            weights=sp.vstack(weights).tocsr(),
            morph_names=names,
            morph_index=index,
            morph_deltas=full[:, index].astype(np.float32),
            landmarks={},
        )
        rig.landmarks = _landmarks(doc, rig)
        return rig


def _landmarks(doc: dict[str, Any], rig: Rig) -> dict[str, np.ndarray]:
    """Our own files carry the landmarks; for others, measure them on the head's vertices."""
    saved = doc.get("asset", {}).get("extras", {}).get("convodrive", {}).get("landmarks")
    if isinstance(saved, dict) and {"crown", "chin", "hairline", "pelvis"} <= set(saved):
        return {k: np.asarray(v, float) for k, v in saved.items()}
    from convodrive.backends.avatar.skinning import RigPoser
    from convodrive.motion.clip import MotionFrame

    sk = rig.skeleton
    poser = RigPoser(rig)
    verts, _ = poser.pose(MotionFrame.neutral())
    world = poser.joint_world(MotionFrame.neutral())
    joint = {JOINT_NAMES[c]: j for j, c in enumerate(sk.canonical) if c >= 0}
    head_j = joint["head"]
    on_head = np.asarray(rig.weights[:, head_j].todense()).ravel() > 0.5
    head_v = verts[on_head] if on_head.sum() > 10 else verts
    head = world[head_j, :3, 3]
    crown_y, low_y = head_v[:, 1].max(), head_v[:, 1].min()
    front_z = head_v[:, 2].max()
    if "left_eye_smplhf" in joint and "right_eye_smplhf" in joint:
        eye_y = 0.5 * (world[joint["left_eye_smplhf"], 1, 3] + world[joint["right_eye_smplhf"], 1, 3])
        chin_y = eye_y - 0.69 * (crown_y - eye_y)  # a face's proportions: the eyes sit mid-head
    else:
        chin_y = low_y
        eye_y = chin_y + 0.45 * (crown_y - chin_y)
    span = crown_y - chin_y
    pelvis = world[joint["pelvis"], :3, 3]
    x = head[0]
    return {
        "head": head,
        "crown": np.array([x, crown_y, head[2]]),
        "chin": np.array([x, chin_y, front_z - 0.02 * span]),
        "mouth": np.array([x, chin_y + 0.17 * span, front_z - 0.03 * span]),
        "hairline": np.array([x, chin_y + 0.72 * span, front_z - 0.1 * span]),
        "left_eye": np.array([head[0] + 0.13 * span, eye_y, front_z - 0.05 * span]),
        "right_eye": np.array([head[0] - 0.13 * span, eye_y, front_z - 0.05 * span]),
        "pelvis": pelvis,
    }
