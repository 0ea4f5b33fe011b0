"""Write a ``Rig`` as a glTF 2.0 binary (.glb): one skinned mesh, its skeleton, ARKit morph targets.

The file is plain glTF 2.0 with no extensions required: Blender, three.js, Unity's glTF importers
and any viewer read it. One mesh holds a primitive per surface; every primitive carries all morph
targets (glTF's rule), stored as sparse accessors so a target that moves only the face costs only
the face; target names are in ``mesh.extras.targetNames``, the convention those tools read.
Joints keep their names (the mannequin's are SMPL-X's), so the file drives from canonical motion
by name. ``extras.convodrive`` keeps what glTF has no slot for (skin scatter, the camera
landmarks), so a file we wrote loads back as the same avatar.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from convodrive import __version__
from convodrive.backends.avatar.rig import Rig, Skeleton
from convodrive.backends.avatar.skinning import vertex_normals, welded_incidence
from convodrive.motion.rotations import matrix_to_quat
from convodrive.plumbing.atomic import atomic_path

FLOAT, UINT8, UINT16, UINT32 = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class _Builder:
    """Accumulates the binary chunk and the JSON's buffer views and accessors."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def view(self, data: bytes, target: int | None = None) -> int:
        self.blob.extend(b"\0" * (-len(self.blob) % 4))
        entry: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if target is not None:
            entry["target"] = target
        self.blob.extend(data)
        self.views.append(entry)
        return len(self.views) - 1

    def accessor(
        self, array: np.ndarray, kind: str, component: int, target: int | None = None, bounds: bool = False
    ) -> int:
        dtype = {FLOAT: np.float32, UINT8: np.uint8, UINT16: np.uint16, UINT32: np.uint32}[component]
        data = np.ascontiguousarray(array, dtype=dtype).reshape(len(array), -1)
        entry: dict[str, Any] = {
            "bufferView": self.view(data.tobytes(), target),
            "componentType": component,
            "count": len(data),
            "type": kind,
        }
        if bounds:
            entry["min"] = data.min(0).tolist()
            entry["max"] = data.max(0).tolist()
        self.accessors.append(entry)
        return len(self.accessors) - 1

    def sparse_vec3(self, values: np.ndarray) -> int:
        """A VEC3 float accessor of ``len(values)`` zeros with the non-zero rows stored sparse
        (at least one row, as glTF requires)."""
        values = np.asarray(values, np.float32)
        rows = np.flatnonzero(np.abs(values).max(1) > 0)
        if len(rows) == 0:
            rows = np.array([0])
        effective = (
            values[rows] if len(rows) == len(values) else np.concatenate([values[rows], np.zeros((1, 3), np.float32)])
        )
        component = UINT16 if len(values) < 65536 else UINT32
        index_dtype = np.uint16 if component == UINT16 else np.uint32
        entry = {
            "componentType": FLOAT,
            "count": len(values),
            "type": "VEC3",
            "min": effective.min(0).tolist(),
            "max": effective.max(0).tolist(),
            "sparse": {
                "count": len(rows),
                "indices": {"bufferView": self.view(rows.astype(index_dtype).tobytes()), "componentType": component},
                "values": {"bufferView": self.view(values[rows].tobytes())},
            },
        }
        self.accessors.append(entry)
        return len(self.accessors) - 1


def _quat_xyzw(m: np.ndarray) -> list[float]:
    w, x, y, z = matrix_to_quat(m)
    return [float(x), float(y), float(z), float(w)]


def _morph_normals(rig: Rig, faces: np.ndarray) -> np.ndarray:
    """(B, V, 3) how each morph target at full weight changes the smooth normals."""
    shading = welded_incidence(rig.rest, rig.normals, faces)
    rest = rig.rest.astype(np.float64)
    base = vertex_normals(rest, faces, shading)
    out = np.zeros((len(rig.morph_names), rig.num_vertices, 3), np.float32)
    for b in range(len(rig.morph_names)):
        moved = rest.copy()
        moved[rig.morph_index] += rig.morph_deltas[b]
        out[b] = vertex_normals(moved, faces, shading) - base
    out[np.abs(out) < 1e-6] = 0.0
    return out


def _four_influences(w: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """JOINTS_0 and WEIGHTS_0 (N, 4) from at most four non-zero weights per row."""
    n = w.shape[0]
    counts = np.diff(w.indptr)
    slot = np.arange(w.nnz) - np.repeat(w.indptr[:-1], counts)
    rows = np.repeat(np.arange(n), counts)
    joints = np.zeros((n, 4), np.int64)
    weights = np.zeros((n, 4), np.float32)
    joints[rows, slot] = w.indices
    weights[rows, slot] = w.data
    return joints, weights / weights.sum(1, keepdims=True)


def _png(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def rig_to_gltf(rig: Rig) -> tuple[dict[str, Any], bytes]:
    """The glTF JSON document and its binary chunk."""
    b = _Builder()
    sk = rig.skeleton
    nodes = _joint_nodes(sk)
    roots = [int(j) for j in np.flatnonzero(sk.parents < 0)]
    mesh_node = len(nodes)
    nodes.append({"name": rig.name, "mesh": 0, "skin": 0})
    materials, images, textures = _materials(rig, b)  # before the meshes: the texture views come first
    mesh: dict[str, Any] = {"name": rig.name, "primitives": _primitives(rig, b)}
    if rig.morph_names:
        mesh["weights"] = [0.0] * len(rig.morph_names)
        mesh["extras"] = {"targetNames": list(rig.morph_names)}
    inverse_bind = np.transpose(sk.inverse_bind, (0, 2, 1)).reshape(-1, 16)  # glTF is column-major
    skin = {
        "name": f"{rig.name} skeleton",
        "joints": list(range(sk.num_joints)),
        "inverseBindMatrices": b.accessor(inverse_bind, "MAT4", FLOAT),
        "skeleton": roots[0],
    }
    doc: dict[str, Any] = {
        "asset": {
            "version": "2.0",
            "generator": f"convodrive {__version__}",
            "extras": {"convodrive": {"landmarks": {k: [float(x) for x in v] for k, v in rig.landmarks.items()}}},
        },
        "scene": 0,
        "scenes": [{"name": rig.name, "nodes": roots + [mesh_node]}],
        "nodes": nodes,
        "meshes": [mesh],
        "skins": [skin],
        "materials": materials,
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.blob)}],
    }
    if images:
        doc["images"], doc["textures"] = images, textures
        doc["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]
    return doc, bytes(b.blob)


def _joint_nodes(sk: Skeleton) -> list[dict[str, Any]]:
    """One node per joint, its rest transform as TRS (identity parts left out) and its children."""
    nodes: list[dict[str, Any]] = []
    for j in range(sk.num_joints):
        node: dict[str, Any] = {"name": sk.names[j]}
        if np.any(np.abs(sk.translation[j]) > 0):
            node["translation"] = [float(x) for x in sk.translation[j]]
        if not np.allclose(sk.rotation[j], np.eye(3)):
            node["rotation"] = _quat_xyzw(sk.rotation[j])
        if not np.allclose(sk.scale[j], 1.0):
            node["scale"] = [float(x) for x in sk.scale[j]]
        children = [int(c) for c in np.flatnonzero(sk.parents == j)]
        if children:
            node["children"] = children
        nodes.append(node)
    return nodes


def _materials(rig: Rig, b: _Builder) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    """The materials, and the images and textures of those with a base colour texture (PNG)."""
    textures: list[dict[str, Any]] = []
    images: list[dict[str, Any]] = []
    materials = []
    for m in rig.materials:
        if not all(0.0 <= c <= 1.0 for c in m.color):
            raise ValueError(f"material {m.name}: base colour factor {m.color} is outside glTF's [0, 1]")
        pbr: dict[str, Any] = {"baseColorFactor": list(m.color), "metallicFactor": 0.0, "roughnessFactor": m.roughness}
        if m.texture is not None:
            images.append({"bufferView": b.view(_png(m.texture)), "mimeType": "image/png"})
            textures.append({"source": len(images) - 1, "sampler": 0})
            pbr["baseColorTexture"] = {"index": len(textures) - 1}
        entry: dict[str, Any] = {
            "name": m.name,
            "pbrMetallicRoughness": pbr,
            "extras": {"convodrive": {"scatter": m.scatter}},
        }
        if m.alpha_cutoff is not None:
            entry["alphaMode"], entry["alphaCutoff"] = "MASK", m.alpha_cutoff
        if m.double_sided:
            entry["doubleSided"] = True
        materials.append(entry)
    return materials, images, textures


def _primitives(rig: Rig, b: _Builder) -> list[dict[str, Any]]:
    """One triangle primitive per surface: its vertex attributes, skin and sparse morph targets."""
    faces_all = np.concatenate([s.faces.astype(np.int64) + s.start for s in rig.surfaces])
    morph_normals = _morph_normals(rig, faces_all) if rig.morph_names else None
    morph_full = np.zeros((len(rig.morph_names), rig.num_vertices, 3), np.float32)
    morph_full[:, rig.morph_index] = rig.morph_deltas
    weights = rig.weights.tocsr()
    influences = max(4, int(np.diff(weights.indptr).max()))
    if influences > 4:
        raise ValueError(f"{rig.name}: {influences} joints on one vertex; glTF's JOINTS_0 takes 4")
    joint_type = UINT8 if rig.skeleton.num_joints < 256 else UINT16
    primitives = []
    for s in rig.surfaces:
        rows = slice(s.start, s.end)
        joints, wts = _four_influences(weights[rows])
        colors = rig.colors[rows]
        opaque = bool(np.all(colors[:, 3] == 1))
        attributes = {
            "POSITION": b.accessor(rig.rest[rows], "VEC3", FLOAT, ARRAY_BUFFER, bounds=True),
            "NORMAL": b.accessor(rig.normals[rows], "VEC3", FLOAT, ARRAY_BUFFER),
            "COLOR_0": b.accessor(
                colors[:, :3] if opaque else colors, "VEC3" if opaque else "VEC4", FLOAT, ARRAY_BUFFER
            ),
            "JOINTS_0": b.accessor(joints, "VEC4", joint_type, ARRAY_BUFFER),
            "WEIGHTS_0": b.accessor(wts, "VEC4", FLOAT, ARRAY_BUFFER),
        }
        if rig.uv is not None:
            attributes["TEXCOORD_0"] = b.accessor(rig.uv[rows], "VEC2", FLOAT, ARRAY_BUFFER)
        prim: dict[str, Any] = {
            "attributes": attributes,
            "indices": b.accessor(s.faces.reshape(-1), "SCALAR", UINT32, ELEMENT_ARRAY_BUFFER),
            "material": s.material,
            "mode": 4,
        }
        if morph_normals is not None:
            prim["targets"] = [
                {"POSITION": b.sparse_vec3(morph_full[k, rows]), "NORMAL": b.sparse_vec3(morph_normals[k, rows])}
                for k in range(len(rig.morph_names))
            ]
        primitives.append(prim)
    return primitives


def glb_bytes(doc: dict[str, Any], blob: bytes) -> bytes:
    """The GLB container: a 12-byte header, the JSON chunk (space padded), the BIN chunk (zero padded)."""
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    blob = blob + b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return b"".join(
        [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(text), b"JSON"),
            text,
            struct.pack("<I4s", len(blob), b"BIN\0"),
            blob,
        ]
    )


def write_glb(rig: Rig, path: Path) -> Path:
    """Write ``rig`` to ``path`` (complete or not at all)."""
    doc, blob = rig_to_gltf(rig)
    with atomic_path(path) as tmp:
        tmp.write_bytes(glb_bytes(doc, blob))
    return path
