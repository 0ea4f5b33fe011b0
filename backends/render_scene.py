"""The avatar's studio: materials, three-point lighting, a backdrop, camera presets, grid layout.

``AvatarRenderer`` owns one offscreen GL context and one avatar mesh whose vertex buffers are
rewritten in place each frame (``glBufferSubData``), so posing costs no GL allocations; K takes
are drawn one after another into the tiles of a grid.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Sequence

import numpy as np

from convodrive.backends.avatar_mesh import MATERIALS, build_avatar
from convodrive.backends.headless_gl import import_pyrender
from convodrive.backends.mesh_build import grid_faces
from convodrive.backends.skinning import AvatarPoser
from convodrive.errors import UserError
from convodrive.motion.clip import MotionFrame

BACKGROUND = (0.80, 0.82, 0.84)


@dataclasses.dataclass(frozen=True)
class CameraPreset:
    target: tuple[float, float, float]
    height: float  # metres to fit vertically at the target
    width: float  # metres to fit horizontally
    elevation_deg: float
    yfov_deg: float = 26.0


CAMERAS: dict[str, CameraPreset] = {
    "full": CameraPreset((0.0, 0.93, 0.0), 2.0, 1.2, 6.0),
    "upper": CameraPreset((0.0, 1.31, 0.02), 0.98, 0.9, 4.0),
    "face": CameraPreset((0.0, 1.618, 0.06), 0.29, 0.25, 2.0),
}


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 1.0, 0.0])) -> np.ndarray:
    """A 4x4 pose for a camera or light at ``eye`` looking at ``target`` (along its -Z)."""
    back = eye - target
    back = back / np.linalg.norm(back)
    right = np.cross(up, back)
    right = right / np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(back, right), back, eye
    return pose


def camera_pose(preset: CameraPreset, aspect: float) -> np.ndarray:
    half = math.tan(math.radians(preset.yfov_deg) / 2)
    dist = max(preset.height / 2 / half, preset.width / 2 / (half * aspect))
    elev = math.radians(preset.elevation_deg)
    target = np.array(preset.target)
    return look_at(target + dist * np.array([0.0, math.sin(elev), math.cos(elev)]), target)


def grid_shape(count: int) -> tuple[int, int]:
    """(rows, cols) for K takes: side by side up to three, then a near-square grid."""
    if count <= 3:
        return 1, max(count, 1)
    cols = math.ceil(math.sqrt(count))
    return math.ceil(count / cols), cols


def parse_resolution(text: str) -> tuple[int, int]:
    """'WxH' -> (W, H); both even (H.264 yuv420p) and within 16..4096."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise UserError(f"resolution {text!r}: expected WIDTHxHEIGHT, e.g. 512x512") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096) or w % 2 or h % 2:
        raise UserError(f"resolution {text!r}: width and height must be even numbers from 16 to 4096")
    return w, h


def _backdrop(pyrender: Any) -> Any:
    """A studio cyclorama: floor curving up into a back wall, shaded lighter toward the middle."""
    xs = np.linspace(-5, 5, 3)
    profile = [(3.0, 0.0), (-0.6, 0.0)] + [(-0.6 - 0.9 * math.sin(a), 0.9 - 0.9 * math.cos(a))
                                           for a in np.linspace(0.2, math.pi / 2, 6)] + [(-1.5, 4.0)]
    pts = np.array([[x, y, z] for z, y in profile for x in xs])
    faces = grid_faces(len(profile), len(xs), wrap=False)
    tri = pts[faces]
    if np.cross(tri[0, 1] - tri[0, 0], tri[0, 2] - tri[0, 0])[1] < 0:
        faces = faces[:, ::-1]
    glow = np.exp(-((pts[:, 1] - 1.3) / 1.8) ** 2)
    base = np.array([0.44, 0.48, 0.53])
    colors = np.concatenate([base * (0.55 + 0.45 * glow[:, None]), np.ones((len(pts), 1))], 1)
    material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1, 1, 1, 1], metallicFactor=0.0, roughnessFactor=1.0)
    prim = pyrender.Primitive(positions=pts, normals=_smooth_normals(pts, faces), color_0=colors, indices=faces,
                              material=material)
    return pyrender.Mesh([prim])


def _smooth_normals(pts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    n = np.zeros_like(pts)
    tri = pts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


class AvatarRenderer:
    """Offscreen renders of the avatar posed by canonical motion frames."""

    def __init__(self, width: int = 512, height: int = 512, camera: str = "upper") -> None:
        if camera not in CAMERAS:
            raise UserError(f"render: camera {camera!r} is not one of {', '.join(CAMERAS)}")
        self.pyrender = pyrender = import_pyrender()
        from OpenGL import GL

        self._gl = GL
        self.width, self.height, self.camera_name = int(width), int(height), camera
        self.avatar = build_avatar()
        self.poser = AvatarPoser(self.avatar)
        self.scene = pyrender.Scene(bg_color=[*BACKGROUND, 1.0], ambient_light=[0.20, 0.20, 0.22])
        self._primitives: list[tuple[Any, int, int, np.ndarray]] = []
        prims = []
        for material, (start, end) in self.avatar.material_ranges.items():
            pbr = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1, 1, 1, 1], metallicFactor=0.0,
                                                     roughnessFactor=MATERIALS[material])
            colors = self.avatar.colors[start:end]
            prim = pyrender.Primitive(positions=self.avatar.rest[start:end], normals=np.tile([0.0, 0.0, 1.0], (end - start, 1)),
                                      color_0=colors, indices=self.avatar.material_faces[material], material=pbr)
            interleaved = np.zeros((end - start, 10), np.float32)
            interleaved[:, 6:] = colors
            prims.append(prim)
            self._primitives.append((prim, start, end, interleaved))
        self.scene.add(pyrender.Mesh(prims))
        self.scene.add(_backdrop(pyrender))
        preset = CAMERAS[camera]
        self.camera = pyrender.PerspectiveCamera(yfov=math.radians(preset.yfov_deg), aspectRatio=self.width / self.height,
                                                 znear=0.05, zfar=30.0)
        self.camera_pose = camera_pose(preset, self.width / self.height)
        self.scene.add(self.camera, pose=self.camera_pose)
        target = np.array(preset.target)
        for color, intensity, where in (((1.0, 0.96, 0.90), 3.2, (1.6, 2.4, 2.6)),   # key: front left, high
                                        ((0.85, 0.90, 1.0), 1.3, (-2.2, 1.2, 2.0)),  # fill: front right, low
                                        ((1.0, 1.0, 1.0), 2.6, (-0.8, 2.6, -2.5))):  # rim: behind
            light = pyrender.DirectionalLight(color=np.array(color), intensity=intensity)
            self.scene.add(light, pose=look_at(target + np.array(where), target))
        try:
            self.renderer = pyrender.OffscreenRenderer(self.width, self.height)
        except Exception as exc:  # a platform that probed fine but cannot open this size
            raise UserError(f"render: cannot open a {self.width}x{self.height} offscreen GL context: {exc}") from None
        self.stats = {"frames": 0, "skin_s": 0.0, "gl_s": 0.0}

    def _upload(self, verts: np.ndarray, normals: np.ndarray) -> None:
        GL = self._gl
        self.renderer._platform.make_current()
        for prim, start, end, buf in self._primitives:
            buf[:, 0:3] = verts[start:end]
            buf[:, 3:6] = normals[start:end]
            if prim._vaid is None:  # not yet in the GL context: pyrender uploads these on first draw
                prim.positions, prim.normals = buf[:, 0:3].copy(), buf[:, 3:6].copy()
            else:
                GL.glBindBuffer(GL.GL_ARRAY_BUFFER, prim._buffers[0])
                GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, buf.nbytes, buf)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)

    def render(self, frame: MotionFrame) -> np.ndarray:
        """One (H, W, 3) uint8 image of the avatar in ``frame``'s pose."""
        t0 = time.perf_counter()
        verts, normals = self.poser.pose(frame)
        t1 = time.perf_counter()
        self._upload(verts, normals)
        color, _ = self.renderer.render(self.scene)
        self.stats["skin_s"] += t1 - t0
        self.stats["gl_s"] += time.perf_counter() - t1
        self.stats["frames"] += 1
        return color

    def render_takes(self, takes: Sequence[MotionFrame]) -> np.ndarray:
        """The takes tiled in a grid (``grid_shape``), each tile W x H."""
        if len(takes) == 1:
            return self.render(takes[0])
        rows, cols = grid_shape(len(takes))
        canvas = np.empty((rows * self.height, cols * self.width, 3), np.uint8)
        canvas[:] = (np.array(BACKGROUND) * 255).astype(np.uint8)
        for i, frame in enumerate(takes):
            r, c = divmod(i, cols)
            canvas[r * self.height:(r + 1) * self.height, c * self.width:(c + 1) * self.width] = self.render(frame)
        return canvas

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel (x, y) of world points in a tile, rows counted from the top."""
        proj = self.camera.get_projection_matrix(self.width, self.height) @ np.linalg.inv(self.camera_pose)
        p = np.concatenate([np.atleast_2d(points), np.ones((len(np.atleast_2d(points)), 1))], 1) @ proj.T
        ndc = p[:, :3] / p[:, 3:4]
        return np.stack([(ndc[:, 0] + 1) / 2 * self.width, (1 - ndc[:, 1]) / 2 * self.height], 1)

    def close(self) -> None:
        if getattr(self, "renderer", None) is not None:
            self.renderer.delete()
            self.renderer = None
