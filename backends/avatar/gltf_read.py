"""Load a user's avatar (glTF 2.0 .glb/.gltf, VRM 1.0 .vrm, or a YAML name map naming one) as a ``Rig``.

What is read: every skinned mesh of the default scene (triangles), meshes hung rigidly from a
bone, their skins (JOINTS_0/WEIGHTS_0 and _1), morph targets (sparse or dense; names from
``mesh.extras.targetNames`` or a VRM 1.0 file's expressions), vertex colours, base colour
textures (PNG or JPEG) and the metallic-roughness factors. Which joint is which canonical joint
comes from ``humanoid``. Anything that makes the avatar unusable (not glTF, no skin, bones
missing) is one ``InputFileError`` line naming the file and the problem.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp

from convodrive.backends.avatar.gltf_assemble import Parts
from convodrive.backends.avatar.gltf_container import GltfData
from convodrive.backends.avatar.humanoid import (
    CANONICAL_TO_VRM,
    REQUIRED_BONES,
    VRM_TO_CANONICAL,
    NameMap,
    arkit_for_name,
    canonical_for_name,
    read_name_map,
)
from convodrive.backends.avatar.rig import Material, Rig, Skeleton, decompose, trs_matrix
from convodrive.motion.rotations import quat_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.plumbing.errors import InputFileError

AVATAR_SUFFIXES = (".glb", ".gltf", ".vrm", ".yaml", ".yml")
_SKIN_LIKE = ("skin", "body", "face", "head", "hand", "arm", "leg", "neck")


def load_avatar(path: Path) -> Rig:
    """The avatar at ``path`` as a rig driven by canonical motion."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in AVATAR_SUFFIXES:
        raise InputFileError(
            path,
            f"unsupported avatar format '{path.suffix or '(none)'}' (expected .glb, .gltf, .vrm or a .yaml name map)",
        )
    if not path.is_file():
        raise InputFileError(path, "no such file")
    names = None
    if suffix in (".yaml", ".yml"):
        names = read_name_map(path)
        path = names.avatar
        if not path.is_file():
            raise InputFileError(path, "no such file (named by 'avatar' in the name map)")
    try:
        return _Reader(path, names).rig()
    except (KeyError, IndexError, TypeError, ValueError, AttributeError) as exc:  # a field not checked up front
        raise InputFileError(path, f"malformed glTF ({exc.__class__.__name__}: {exc})") from None


class _Reader(GltfData):
    """The document's default scene read as a rig: skeleton, skinned and rigid meshes, morphs."""

    def __init__(self, path: Path, names: NameMap | None) -> None:
        super().__init__(path)
        self.names = names
        self.num_joints = 0

    def node_local(self, index: int) -> np.ndarray:
        node = self.doc["nodes"][index]
        if "matrix" in node:
            return np.asarray(node["matrix"], float).reshape(4, 4).T
        q = node.get("rotation", [0, 0, 0, 1])
        rot = quat_to_matrix(np.array([q[3], q[0], q[1], q[2]], float))
        return trs_matrix(node.get("translation", [0, 0, 0]), rot, node.get("scale", [1, 1, 1]))

    def rig(self) -> Rig:
        doc = self.doc
        if doc.get("extensions", {}).get("VRM") is not None and "VRMC_vrm" not in doc.get("extensions", {}):
            raise self.fail(
                "VRM 0.x is not supported; convert it to VRM 1.0 (for example with UniVRM or the VRM Blender add-on)"
            )
        nodes = doc.get("nodes", [])
        parent = np.full(len(nodes), -1)
        for i, node in enumerate(nodes):
            for c in node.get("children", []):
                parent[c] = i
        scene = (
            doc.get("scenes", [{}])[doc.get("scene", 0)]
            if doc.get("scenes")
            else {"nodes": [i for i in range(len(nodes)) if parent[i] < 0]}
        )
        in_scene = set()
        stack = list(scene.get("nodes", []))
        while stack:
            i = stack.pop()
            in_scene.add(i)
            stack += nodes[i].get("children", [])
        world = {}
        for i in sorted(in_scene, key=lambda k: _depth(parent, k)):
            world[i] = self.node_local(i) if parent[i] < 0 else world[parent[i]] @ self.node_local(i)

        skinned = [i for i in sorted(in_scene) if "mesh" in nodes[i] and "skin" in nodes[i]]
        if not skinned:
            raise self.fail("has no skinned mesh (no skin): an avatar needs a mesh bound to a skeleton")
        joint_nodes = sorted(
            {j for i in skinned for j in doc["skins"][nodes[i]["skin"]]["joints"]}, key=lambda k: _depth(parent, k)
        )
        joint_of = {n: j for j, n in enumerate(joint_nodes)}
        inverse_bind = np.zeros((len(joint_nodes), 4, 4))
        have_bind = np.zeros(len(joint_nodes), bool)
        for i in skinned:
            skin = doc["skins"][nodes[i]["skin"]]
            ibm = (
                self.accessor(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
                if "inverseBindMatrices" in skin
                else np.tile(np.eye(4), (len(skin["joints"]), 1, 1))
            )
            for k, n in enumerate(skin["joints"]):
                if not have_bind[joint_of[n]]:
                    inverse_bind[joint_of[n]], have_bind[joint_of[n]] = ibm[k], True
        missing_nodes = [n for n in joint_nodes if n not in world]
        if missing_nodes:
            raise self.fail(f"skin joint node {missing_nodes[0]} is not in the scene")
        skeleton = self.skeleton(joint_nodes, parent, world, inverse_bind)
        self.num_joints = skeleton.num_joints

        parts = Parts()
        for i in skinned:
            skin_joints = [joint_of[n] for n in doc["skins"][nodes[i]["skin"]]["joints"]]
            self.add_mesh(parts, nodes[i]["mesh"], skin_joints, None)
        for i in sorted(in_scene):  # meshes hung from a bone without a skin: rigid on that bone
            if "mesh" in nodes[i] and "skin" not in nodes[i]:
                bone = _nearest(parent, i, joint_of)
                if bone is not None:
                    j = joint_of[bone]
                    bind = np.linalg.inv(world[bone] @ inverse_bind[j]) @ world[i]
                    self.add_mesh(parts, nodes[i]["mesh"], [j], bind)
        if not parts.surfaces:
            raise self.fail("has no triangles in its skinned meshes")
        return parts.to_rig(self.path.stem, self.doc, skeleton)

    def skeleton(
        self, joint_nodes: list[int], parent: np.ndarray, world: dict[int, np.ndarray], inverse_bind: np.ndarray
    ) -> Skeleton:
        doc, nodes = self.doc, self.doc["nodes"]
        joint_of = {n: j for j, n in enumerate(joint_nodes)}
        parents = np.array(
            [joint_of.get(_nearest(parent, parent[n], joint_of) if parent[n] >= 0 else -1, -1) for n in joint_nodes]
        )
        translation, rotation, scale = [], [], []
        for j, n in enumerate(joint_nodes):
            p = parents[j]
            local = world[n] if p < 0 else np.linalg.inv(world[joint_nodes[p]]) @ world[n]
            t, r, s = decompose(local)
            translation.append(t)
            rotation.append(r)
            scale.append(s)
        canonical = np.full(len(joint_nodes), -1)
        claimed: dict[str, int] = {}
        vrm = doc.get("extensions", {}).get("VRMC_vrm", {}).get("humanoid", {}).get("humanBones", {})
        for bone, entry in vrm.items():
            name = VRM_TO_CANONICAL.get(bone)
            if name and entry.get("node") in joint_of:
                claimed.setdefault(name, joint_of[entry["node"]])
        by_name = {nodes[n].get("name", ""): j for j, n in enumerate(joint_nodes)}
        if self.names is not None:
            for name, node_name in self.names.bones.items():
                if node_name not in by_name:
                    raise self.fail(
                        f"the name map's bone {CANONICAL_TO_VRM.get(name, name)}: {node_name!r} is not a joint of this avatar's skin"
                    )
                claimed[name] = by_name[node_name]
        for j, n in enumerate(joint_nodes):  # parents first, so a rig's upper "Spine" wins over a twin deeper down
            name = canonical_for_name(nodes[n].get("name", ""))
            if name and name not in claimed and j not in claimed.values():
                claimed[name] = j
        for name, j in claimed.items():
            canonical[j] = JOINT_INDEX[name]
        missing = [b for b in REQUIRED_BONES if VRM_TO_CANONICAL[b] not in claimed]
        if missing:
            raise self.fail(
                f"missing humanoid bones {', '.join(missing)} (name its joints with VRM or SMPL-X names, "
                "or give a YAML name map: avatar: FILE, bones: {hips: NODE, ...})"
            )
        return Skeleton(
            names=tuple(nodes[n].get("name", f"node{n}") for n in joint_nodes),
            parents=parents,
            translation=np.array(translation),
            rotation=np.array(rotation),
            scale=np.array(scale),
            inverse_bind=inverse_bind,
            canonical=canonical,
        )

    def add_mesh(self, parts: Parts, mesh_index: int, joints: list[int], rigid: np.ndarray | None) -> None:
        """Append a mesh's triangle primitives; ``rigid`` (a 4x4) binds every vertex to ``joints[0]``."""
        mesh = self.doc["meshes"][mesh_index]
        target_names = list(mesh.get("extras", {}).get("targetNames", []))
        default_weights = list(mesh.get("weights", []))
        arkit = self.morph_channels(mesh_index, target_names)
        for prim in mesh.get("primitives", []):
            mode = prim.get("mode", 4)
            if mode not in (4, 5, 6) or "POSITION" not in prim.get("attributes", {}):
                continue
            attrs = prim["attributes"]
            pos = self.accessor(attrs["POSITION"])[:, :3]
            n = len(pos)
            faces = self.accessor(prim["indices"]).ravel() if "indices" in prim else np.arange(n)
            faces = _triangles(faces.astype(np.int64), mode)
            if len(faces) == 0:
                continue
            if faces.max() >= n:
                raise self.fail(f"mesh {mesh_index}: a triangle refers to vertex {int(faces.max())} of {n}")
            normals = self.accessor(attrs["NORMAL"])[:, :3] if "NORMAL" in attrs else None
            deltas: dict[str, np.ndarray] = {}
            base = np.zeros((n, 3))
            for k, target in enumerate(prim.get("targets", [])):
                if "POSITION" not in target:
                    continue
                d = self.accessor(target["POSITION"])[:, :3]
                for channel, weight in arkit.get(k, []):
                    deltas[channel] = deltas.get(channel, 0) + weight * d
                if k not in arkit and k < len(default_weights) and default_weights[k]:
                    base += default_weights[k] * d  # a shape the file shows but nothing drives: keep it
            pos = pos + base
            if rigid is not None:
                pos = pos @ rigid[:3, :3].T + rigid[:3, 3]
                normals = None if normals is None else normals @ np.linalg.inv(rigid[:3, :3])
                weights = sp.csr_matrix((np.ones(n), (np.arange(n), np.full(n, joints[0]))))
            else:
                weights = self.skin_weights(attrs, n, joints)
            colors = np.ones((n, 4))
            if "COLOR_0" in attrs:
                c = self.accessor(attrs["COLOR_0"])
                colors[:, : c.shape[1]] = c
            uv = self.accessor(attrs["TEXCOORD_0"])[:, :2] if "TEXCOORD_0" in attrs else None
            parts.add(self.material(prim.get("material")), pos, normals, colors, uv, faces, weights, deltas)

    def skin_weights(self, attrs: dict[str, int], n: int, joints: list[int]) -> sp.csr_matrix:
        rows, cols, vals = [], [], []
        for set_ in range(4):
            if f"JOINTS_{set_}" not in attrs or f"WEIGHTS_{set_}" not in attrs:
                break
            j = self.accessor(attrs[f"JOINTS_{set_}"]).astype(np.int64)
            w = self.accessor(attrs[f"WEIGHTS_{set_}"])
            if j.max(initial=0) >= len(joints):
                raise self.fail(f"a vertex names joint {int(j.max())} but its skin has {len(joints)}")
            rows.append(np.repeat(np.arange(n), j.shape[1]))
            cols.append(np.asarray(joints)[j].ravel())
            vals.append(w.ravel())
        if not rows:
            raise self.fail("a skinned mesh has no JOINTS_0/WEIGHTS_0")
        r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
        keep = v > 0
        m = sp.csr_matrix((v[keep], (r[keep], c[keep])), shape=(n, self.num_joints))
        total = np.asarray(m.sum(1)).ravel()
        if np.any(total <= 0):
            raise self.fail("a skinned vertex has no weight on any joint")
        return sp.diags(1.0 / total) @ m

    def morph_channels(self, mesh_index: int, target_names: list[str]) -> dict[int, list[tuple[str, float]]]:
        """Morph target index -> the ARKit channels that drive it (with their weights)."""
        out: dict[int, list[tuple[str, float]]] = {}
        wanted = {v: k for k, v in self.names.morphs.items()} if self.names else {}
        for k, name in enumerate(target_names):
            channel = wanted.get(name) or (None if wanted and name not in wanted else arkit_for_name(name))
            if channel:
                out.setdefault(k, []).append((channel, 1.0))
        expressions = self.doc.get("extensions", {}).get("VRMC_vrm", {}).get("expressions", {})
        for group in ("preset", "custom"):  # Perfect Sync: ARKit-named expressions binding targets
            for name, expr in expressions.get(group, {}).items():
                channel = arkit_for_name(name)
                if channel is None:
                    continue
                for bind in expr.get("morphTargetBinds", []):
                    node = (
                        self.doc["nodes"][bind.get("node", -1)]
                        if 0 <= bind.get("node", -1) < len(self.doc["nodes"])
                        else {}
                    )
                    if node.get("mesh") == mesh_index and bind.get("index") not in out:
                        out.setdefault(bind["index"], []).append((channel, float(bind.get("weight", 1.0))))
        return out

    def material(self, index: int | None) -> Material:
        if index is None:
            return Material("default")
        m = self.doc["materials"][index]
        pbr = m.get("pbrMetallicRoughness", {})
        name = m.get("name", f"material{index}")
        ours = m.get("extras", {}).get("convodrive", {}) if isinstance(m.get("extras"), dict) else {}
        scatter = ours.get("scatter", 0.6 if any(w in name.lower() for w in _SKIN_LIKE) else 0.0)
        texture = None
        if "baseColorTexture" in pbr:
            try:
                texture = self.image(self.doc["textures"][pbr["baseColorTexture"]["index"]]["source"])
            except (KeyError, IndexError):
                texture = None
        mode = m.get("alphaMode", "OPAQUE")
        return Material(
            name=name,
            color=tuple(float(x) for x in pbr.get("baseColorFactor", [1, 1, 1, 1])),  # type: ignore[arg-type]
            roughness=float(pbr.get("roughnessFactor", 1.0)),
            scatter=float(scatter),
            texture=texture,
            alpha_cutoff=float(m.get("alphaCutoff", 0.5)) if mode == "MASK" else (0.05 if mode == "BLEND" else None),
            double_sided=bool(m.get("doubleSided", False)),
        )


def _depth(parent: np.ndarray, node: int) -> int:
    d = 0
    while parent[node] >= 0:
        node, d = parent[node], d + 1
    return d


def _nearest(parent: np.ndarray, node: int, among: dict[int, int]) -> int | None:
    """``node`` or its nearest ancestor that is in ``among``."""
    while node >= 0:
        if node in among:
            return node
        node = parent[node]
    return None


def _triangles(indices: np.ndarray, mode: int) -> np.ndarray:
    if mode == 4:
        return indices[: len(indices) // 3 * 3].reshape(-1, 3)
    k = np.arange(len(indices) - 2)
    if mode == 5:  # strip: every other triangle flips to keep the winding
        tri = np.stack([indices[k], indices[k + 1], indices[k + 2]], 1)
        tri[1::2] = tri[1::2][:, [1, 0, 2]]
        return tri
    return np.stack([np.full(len(k), indices[0]), indices[k + 1], indices[k + 2]], 1)  # fan
