"""The structure of a glTF document checked before anything is read from it.

The reader walks the node graph, follows indices from nodes to meshes, skins, accessors, buffer
views and buffers, and allocates what accessors claim. A shared avatar may be hostile or simply
broken: a ``children`` cycle would make those walks loop for ever, an index out of range or a
field of the wrong type would surface as a traceback, and an accessor claiming two billion
elements would exhaust memory. ``check_document`` proves the graph is a forest, every index points
at an entry of the right table, every accessor fits in its buffer view and every view in its
buffer, so the reader can trust what it follows. Each problem is one ``InputFileError`` line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from convodrive.plumbing.errors import InputFileError

COMPONENTS: dict[int, type[np.generic]] = {
    5120: np.int8,
    5121: np.uint8,
    5122: np.int16,
    5123: np.uint16,
    5125: np.uint32,
    5126: np.float32,
}
"""glTF componentType -> its NumPy type (little-endian in the file)."""
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
MAX_VALUES = 1 << 26
"""Values (count x width) one accessor may hold: 64 M, far above any avatar's (a 100k-vertex mesh
has 300k positions), low enough that an accessor with no buffer view cannot exhaust memory."""
MAX_BUFFER_BYTES = 1 << 31
_TABLES = (
    "scenes",
    "nodes",
    "skins",
    "meshes",
    "accessors",
    "bufferViews",
    "buffers",
    "materials",
    "textures",
    "images",
)


def check_document(doc: dict[str, Any], path: Path) -> None:
    """Raise an ``InputFileError`` naming ``path`` and the first structural problem of ``doc``."""
    _Checker(doc, path).run()


class _Checker:
    def __init__(self, doc: dict[str, Any], path: Path) -> None:
        self.doc, self.path = doc, path

    def fail(self, problem: str) -> InputFileError:
        return InputFileError(self.path, problem)

    def table(self, name: str) -> list[dict[str, Any]]:
        value = self.doc.get(name, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self.fail(f"'{name}' must be a list of objects")
        return value

    def index(self, value: Any, table: str, where: str) -> int:
        size = len(self.table(table))
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < size:
            raise self.fail(f"{where} refers to {table} {value!r}, but there are {size}")
        return value

    def indices(self, value: Any, table: str, where: str) -> list[int]:
        if not isinstance(value, list):
            raise self.fail(f"{where} must be a list of {table} indices")
        return [self.index(v, table, where) for v in value]

    def whole(self, value: Any, where: str, low: int = 0, high: int = MAX_BUFFER_BYTES) -> int:
        if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
            raise self.fail(f"{where} must be a whole number from {low} to {high}, not {value!r}")
        return value

    def numbers(self, value: Any, size: int, where: str) -> None:
        if (
            not isinstance(value, list)
            or len(value) != size
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        ):
            raise self.fail(f"{where} must be {size} numbers")

    def run(self) -> None:
        for name in _TABLES:
            self.table(name)
        self.check_buffers()
        for i, acc in enumerate(self.table("accessors")):
            self.check_accessor(i, acc)
        self.check_nodes()
        scenes = self.table("scenes")
        if scenes:
            self.index(self.doc.get("scene", 0), "scenes", "scene")
        for i, scene in enumerate(scenes):
            self.indices(scene.get("nodes", []), "nodes", f"scene {i}")
        for i, skin in enumerate(self.table("skins")):
            self.indices(skin.get("joints"), "nodes", f"skin {i} joints")
            if "inverseBindMatrices" in skin:
                self.index(skin["inverseBindMatrices"], "accessors", f"skin {i} inverseBindMatrices")
        for i, mesh in enumerate(self.table("meshes")):
            self.check_mesh(i, mesh)
        for i, material in enumerate(self.table("materials")):
            pbr = material.get("pbrMetallicRoughness", {})
            texture = pbr.get("baseColorTexture") if isinstance(pbr, dict) else None
            if texture is not None:
                self.index(
                    texture.get("index") if isinstance(texture, dict) else None, "textures", f"material {i} texture"
                )
        for i, texture in enumerate(self.table("textures")):
            if "source" in texture:
                self.index(texture["source"], "images", f"texture {i} source")
        for i, image in enumerate(self.table("images")):
            if "bufferView" in image:
                self.index(image["bufferView"], "bufferViews", f"image {i}")

    def check_buffers(self) -> None:
        lengths = [
            self.whole(b.get("byteLength"), f"buffer {i} byteLength") for i, b in enumerate(self.table("buffers"))
        ]
        for i, view in enumerate(self.table("bufferViews")):
            where = f"bufferView {i}"
            b = self.index(view.get("buffer"), "buffers", where)
            end = self.whole(view.get("byteOffset", 0), f"{where} byteOffset") + self.whole(
                view.get("byteLength"), f"{where} byteLength"
            )
            if end > lengths[b]:
                raise self.fail(f"{where} ends at byte {end}, past its buffer's {lengths[b]}")
            if "byteStride" in view:
                self.whole(view["byteStride"], f"{where} byteStride", 4, 252)

    def check_accessor(self, i: int, acc: dict[str, Any]) -> None:
        where = f"accessor {i}"
        if acc.get("componentType") not in COMPONENTS or acc.get("type") not in WIDTHS:
            raise self.fail(f"{where} has an unknown componentType or type")
        width, size = WIDTHS[acc["type"]], np.dtype(COMPONENTS[acc["componentType"]]).itemsize
        count = self.whole(acc.get("count"), f"{where} count", 1, MAX_VALUES // width)
        if "bufferView" in acc:
            view = self.table("bufferViews")[self.index(acc["bufferView"], "bufferViews", where)]
            offset = self.whole(acc.get("byteOffset", 0), f"{where} byteOffset")
            item = size * width
            end = offset + (count - 1) * view.get("byteStride", item) + item
            if end > view["byteLength"]:
                raise self.fail(
                    f"{where} needs {end} bytes of bufferView {acc['bufferView']}, which has {view['byteLength']}"
                )
        sparse = acc.get("sparse")
        if sparse is not None:
            if not isinstance(sparse, dict) or not all(isinstance(sparse.get(k), dict) for k in ("indices", "values")):
                raise self.fail(f"{where} sparse must hold indices and values")
            n = self.whole(sparse.get("count"), f"{where} sparse count", 1, count)
            if sparse["indices"].get("componentType") not in (5121, 5123, 5125):
                raise self.fail(f"{where} sparse indices have an unknown componentType")
            for part, item in (
                ("indices", np.dtype(COMPONENTS[sparse["indices"]["componentType"]]).itemsize),
                ("values", size * width),
            ):
                view = self.table("bufferViews")[
                    self.index(sparse[part].get("bufferView"), "bufferViews", f"{where} sparse {part}")
                ]
                end = self.whole(sparse[part].get("byteOffset", 0), f"{where} sparse {part} byteOffset") + n * item
                if end > view["byteLength"]:
                    raise self.fail(f"{where} sparse {part} need {end} bytes of a bufferView of {view['byteLength']}")

    def check_nodes(self) -> None:
        """Indices in range, numbers where numbers go, and a forest: one parent at most, no cycle."""
        nodes = self.table("nodes")
        parent = [-1] * len(nodes)
        for i, node in enumerate(nodes):
            for c in self.indices(node.get("children", []), "nodes", f"node {i} children"):
                if parent[c] >= 0 or c == i:
                    raise self.fail(
                        f"node {c} has two parents (nodes {parent[c]} and {i}): the node graph must be a tree"
                    )
                parent[c] = i
            for key, table in (("mesh", "meshes"), ("skin", "skins")):
                if key in node:
                    self.index(node[key], table, f"node {i} {key}")
            for key, size in (("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)):
                if key in node:
                    self.numbers(node[key], size, f"node {i} {key}")
        for i in range(len(nodes)):
            node, steps = i, 0
            while parent[node] >= 0:
                node, steps = parent[node], steps + 1
                if steps > len(nodes):
                    raise self.fail(f"node {i} is its own ancestor: the node graph has a cycle")

    def check_mesh(self, i: int, mesh: dict[str, Any]) -> None:
        prims = mesh.get("primitives", [])
        if not isinstance(prims, list) or not all(isinstance(p, dict) for p in prims):
            raise self.fail(f"mesh {i} primitives must be a list of objects")
        names = (mesh.get("extras") or {}).get("targetNames", []) if isinstance(mesh.get("extras"), dict) else []
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise self.fail(f"mesh {i} extras.targetNames must be a list of names")
        if "weights" in mesh:
            self.numbers(
                mesh["weights"], len(mesh["weights"]) if isinstance(mesh["weights"], list) else -1, f"mesh {i} weights"
            )
        for k, prim in enumerate(prims):
            where = f"mesh {i} primitive {k}"
            attributes, targets = prim.get("attributes", {}), prim.get("targets", [])
            if not isinstance(attributes, dict) or not isinstance(targets, list):
                raise self.fail(f"{where}: attributes must be an object and targets a list")
            for name, acc in attributes.items():
                self.index(acc, "accessors", f"{where} {name}")
            for t, target in enumerate(targets):
                if not isinstance(target, dict):
                    raise self.fail(f"{where} target {t} must be an object")
                for name, acc in target.items():
                    self.index(acc, "accessors", f"{where} target {t} {name}")
            if "indices" in prim:
                self.index(prim["indices"], "accessors", f"{where} indices")
            if "material" in prim:
                self.index(prim["material"], "materials", f"{where} material")
