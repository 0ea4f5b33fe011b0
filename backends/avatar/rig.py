"""A skinned avatar as the renderer and the glTF reader and writer see it, whatever it came from.

The built-in mannequin (``mannequin.build_mannequin``) and an avatar loaded from glTF or VRM
(``gltf_read.load_avatar``) both become a ``Rig``: bind-pose vertices grouped into surfaces (one
material each), a skeleton of nodes with rest transforms and inverse bind matrices, skin weights,
and morph targets named by ARKit. Each skeleton joint may name the canonical joint that drives it;
``skinning.RigPoser`` turns canonical motion into posed vertices through that map. Keeping one
form is what makes an exported mannequin render exactly like the built-in one.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import scipy.sparse as sp


@dataclasses.dataclass(frozen=True)
class Material:
    """What the lean shader needs of a surface (glTF metallic-roughness, minus the metal)."""

    name: str
    color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    """Base colour factor, linear RGBA; multiplies the vertex colours and the texture."""
    roughness: float = 0.6
    scatter: float = 0.0
    """0..1: how much light bleeds red past the shadow line, as it does in skin."""
    texture: np.ndarray | None = dataclasses.field(default=None, compare=False)
    """(H, W, 4) uint8 base colour texture in sRGB, read through the rig's ``uv``."""
    alpha_cutoff: float | None = None
    """Texels below this alpha are not drawn (glTF ``MASK``); None draws every texel."""
    double_sided: bool = False


@dataclasses.dataclass
class Surface:
    """A run of the rig's vertices drawn with one material."""

    material: int
    start: int
    end: int
    faces: np.ndarray
    """(F, 3) uint32 triangle corners, counted from ``start``."""


@dataclasses.dataclass
class Skeleton:
    """Joints in parent-before-child order, each with its rest transform relative to its parent.

    A root joint's rest transform is its whole placement in the scene (the glTF nodes above the
    skeleton are folded into it). ``canonical`` names the canonical joint (index into
    ``motion.skeleton.JOINT_NAMES``) that drives each joint, or -1 for a joint that follows its
    parent, such as a hair or a twist bone.
    """

    names: tuple[str, ...]
    parents: np.ndarray  # (J,) int, -1 for a root; parents come before children
    translation: np.ndarray  # (J, 3) rest translation in the parent's frame
    rotation: np.ndarray  # (J, 3, 3) rest rotation relative to the parent
    scale: np.ndarray  # (J, 3) rest scale
    inverse_bind: np.ndarray  # (J, 4, 4) bind-pose world -> joint space
    canonical: np.ndarray  # (J,) int canonical joint index, or -1

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def rest_world(self) -> np.ndarray:
        """(J, 4, 4) world transforms of the joints in the rest pose."""
        out = np.empty((self.num_joints, 4, 4))
        for j, p in enumerate(self.parents):
            local = trs_matrix(self.translation[j], self.rotation[j], self.scale[j])
            out[j] = local if p < 0 else out[p] @ local
        return out


@dataclasses.dataclass
class Rig:
    """A skinned, morphable avatar in glTF's frame: metres, Y up, facing +Z."""

    name: str
    rest: np.ndarray  # (V, 3) float32 bind-pose positions
    normals: np.ndarray  # (V, 3) float32 bind-pose unit normals
    colors: np.ndarray  # (V, 4) float32 linear RGBA vertex colours (ones when the file has none)
    uv: np.ndarray | None  # (V, 2) float32 texture coordinates, or None
    surfaces: list[Surface]
    materials: list[Material]
    skeleton: Skeleton
    weights: sp.csr_matrix  # (V, J) skin weights, rows sum to one
    morph_names: tuple[str, ...]  # ARKit names, in the order of ``morph_deltas``
    morph_index: np.ndarray  # (S,) vertices any morph target moves
    morph_deltas: np.ndarray  # (B, S, 3) float32 position offsets at weight 1
    landmarks: dict[str, np.ndarray]
    """Rest positions the cameras and tests aim at: ``head``, ``chin``, ``mouth``, ``left_eye``,
    ``right_eye``, ``crown``, ``pelvis`` at least."""

    @property
    def num_vertices(self) -> int:
        return len(self.rest)

    def morph(self, name: str) -> np.ndarray:
        """(V, 3) the named morph target's offsets over every vertex (zeros where it moves none)."""
        out = np.zeros((self.num_vertices, 3), np.float32)
        out[self.morph_index] = self.morph_deltas[self.morph_names.index(name)]
        return out


def trs_matrix(translation: np.ndarray, rotation: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """4x4 T @ R @ S, glTF's order of a node's transform."""
    m = np.eye(4)
    m[:3, :3] = np.asarray(rotation, float) * np.asarray(scale, float)[None, :]
    m[:3, 3] = translation
    return m


def decompose(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Translation, rotation (3x3, proper) and scale of an affine 4x4 without shear."""
    m = np.asarray(matrix, float)
    scale = np.linalg.norm(m[:3, :3], axis=0)
    rot = m[:3, :3] / np.where(scale > 1e-12, scale, 1.0)[None, :]
    if np.linalg.det(rot) < 0:  # a mirror: carry it in the scale, keep the rotation proper
        scale[0], rot[:, 0] = -scale[0], -rot[:, 0]
    return m[:3, 3].copy(), rot, scale


def csr(values: np.ndarray, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> sp.csr_matrix:
    """A sparse matrix from (value, row, column) triples. scipy.sparse is imported here, when a rig
    is built, so that loading the render backend (``convodrive plugins``) does not wait for it."""
    import scipy.sparse

    return scipy.sparse.csr_matrix((values, (rows, cols)), shape=shape)


def sparse_weights(dense: np.ndarray, influences: int = 4) -> sp.csr_matrix:
    """Keep the ``influences`` largest weights per vertex, renormalised to sum to one."""
    keep = np.argsort(-dense, axis=1)[:, :influences]
    rows = np.repeat(np.arange(len(dense)), keep.shape[1])
    vals = np.take_along_axis(dense, keep, 1)
    total = vals.sum(1, keepdims=True)
    vals = vals / np.where(total > 0, total, 1.0)
    m = csr(vals.ravel(), rows, keep.ravel(), dense.shape)
    m.eliminate_zeros()
    return m
