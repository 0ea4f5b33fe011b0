"""The avatar's studio: materials, three-point lighting, a backdrop, camera presets, grid layout.

``AvatarRenderer`` owns one offscreen GL context and one rig (the built-in mannequin or an avatar
loaded from a file) whose vertex buffers are rewritten in place each frame (``glBufferSubData``),
so posing costs no GL allocations; K takes are drawn one after another into the tiles of a grid.
Cameras frame the rig by its own landmarks, so a taller or smaller avatar is framed alike.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from convodrive.backends.avatar import avatar_shader
from convodrive.backends.avatar.mesh_build import smoothstep
from convodrive.backends.avatar.pyrender_gl import delete_offscreen, import_pyrender
from convodrive.backends.avatar.rig import Rig, Surface
from convodrive.backends.avatar.skinning import RigPoser
from convodrive.motion.clip import MotionFrame
from convodrive.plumbing.errors import UserError

WALL_Z = -1.3
WALL_COLOR = (0.62, 0.66, 0.71)
FLOOR_COLOR = (0.50, 0.52, 0.55)
BACKGROUND = WALL_COLOR


@dataclasses.dataclass(frozen=True)
class CameraPreset:
    """A framing in units of the rig's head height (chin to crown), around one of its landmarks."""

    anchor: str  # a landmark of the rig, or "floor" (the point under the pelvis)
    offset: tuple[float, float, float]  # from the anchor, in head heights
    height: float  # head heights to fit vertically at the target
    width: float  # head heights to fit horizontally
    elevation_deg: float
    yfov_deg: float = 26.0
    azimuth_deg: float = 0.0  # about Y, from the front; +90 looks at the character's left side


CAMERAS: dict[str, CameraPreset] = {
    "full": CameraPreset("floor", (0.0, 3.7, 0.0), 7.9, 4.8, 6.0),
    "upper": CameraPreset("crown", (0.0, -1.45, 0.02), 3.15, 3.0, 4.0),
    "face": CameraPreset("face", (0.0, 0.02, 0.0), 1.17, 1.0, 2.0),
}
"""``upper`` frames the chest up with the face over a fifth of the frame's height, large enough
to read the lips; ``face`` fills the frame with the head."""


def frame_target(preset: CameraPreset, rig: Rig) -> tuple[np.ndarray, float, float]:
    """World target point, height and width (metres) of ``preset`` on ``rig``."""
    marks = rig.landmarks
    head = float(marks["crown"][1] - marks["chin"][1])
    if preset.anchor == "floor":
        anchor = np.array([marks["pelvis"][0], 0.0, marks["pelvis"][2]])
    elif preset.anchor == "face":
        anchor = 0.5 * (marks["chin"] + marks["hairline"])
    else:
        anchor = np.array(marks[preset.anchor], float)
    return anchor + head * np.array(preset.offset), head * preset.height, head * preset.width


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """A 4x4 pose for a camera or light at ``eye`` looking at ``target`` (along its -Z); Y is up by default."""
    up = np.array([0.0, 1.0, 0.0]) if up is None else up
    back = eye - target
    back = back / np.linalg.norm(back)
    right = np.cross(up, back)
    right = right / np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(back, right), back, eye
    return pose


def camera_pose(preset: CameraPreset, rig: Rig, aspect: float) -> np.ndarray:
    target, height, width = frame_target(preset, rig)
    half = math.tan(math.radians(preset.yfov_deg) / 2)
    dist = max(height / 2 / half, width / 2 / (half * aspect))
    elev, azim = math.radians(preset.elevation_deg), math.radians(preset.azimuth_deg)
    direction = np.array([math.cos(elev) * math.sin(azim), math.sin(elev), math.cos(elev) * math.cos(azim)])
    return look_at(target + dist * direction, target)


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


def backdrop_image(width: int, height: int, camera: Any, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The studio behind the avatar, ray-cast once per camera: a floor meeting a softly lit wall.

    Returns the (H, W, 3) float image and the (H, W, 3) world point each pixel sees, which the
    per-frame contact shadow uses. Drawn in NumPy and composited where the GL depth is empty,
    because a full-screen backdrop mesh would double the software rasteriser's shading work.
    """
    ys, xs = np.mgrid[0:height, 0:width] + 0.5
    proj = camera.get_projection_matrix(width, height)
    ndc = np.stack([xs / width * 2 - 1, 1 - ys / height * 2], -1)
    d = np.stack([ndc[..., 0] / proj[0, 0], ndc[..., 1] / proj[1, 1], -np.ones_like(xs)], -1) @ pose[:3, :3].T
    eye = pose[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[..., 1] < 0, -eye[1] / d[..., 1], np.inf)
        t_wall = np.where(d[..., 2] < 0, (WALL_Z - eye[2]) / d[..., 2], np.inf)
    t = np.minimum(t_floor, t_wall)
    t = np.where(np.isfinite(t), t, 50.0)
    world = eye + d * t[..., None]
    wall_glow = np.exp(-((world[..., 0] / 2.4) ** 2 + ((world[..., 1] - 1.35) / 1.5) ** 2))
    wall = np.array(WALL_COLOR) * (0.72 + 0.28 * wall_glow)[..., None]
    floor_glow = np.exp(-(world[..., 0] ** 2 + (world[..., 2] - 0.3) ** 2) / 6.0)
    floor = np.array(FLOOR_COLOR) * (0.78 + 0.22 * floor_glow)[..., None]
    # a cove: blend floor into wall over the last 40 cm before the wall, like a studio cyclorama
    cove = smoothstep(WALL_Z + 0.4, WALL_Z, world[..., 2]) * (t_floor <= t_wall)
    is_floor = (t_floor <= t_wall)[..., None]
    image = np.where(is_floor, floor * (1 - cove[..., None]) + wall * cove[..., None], wall)
    return image.astype(np.float32), world.astype(np.float32)


@contextlib.contextmanager
def msaa_samples(samples: int) -> Iterator[None]:
    """Make pyrender allocate its offscreen framebuffer with ``samples`` (it hard-codes 4).

    4x MSAA costs a software rasteriser about 2.5x per frame, so it is an option, not the default.
    pyrender allocates the framebuffer on the first render, which must happen inside this block.
    """
    import pyrender.renderer as pr_renderer

    original = pr_renderer.glRenderbufferStorageMultisample
    pr_renderer.glRenderbufferStorageMultisample = lambda target, _n, *args: original(target, samples, *args)
    try:
        yield
    finally:
        pr_renderer.glRenderbufferStorageMultisample = original


class AvatarRenderer:
    """Offscreen renders of the avatar posed by canonical motion frames."""

    def __init__(
        self,
        width: int = 512,
        height: int = 512,
        camera: str | CameraPreset = "upper",
        antialias: bool = False,
        lean_shader: bool = True,
        rig: Rig | None = None,
    ) -> None:
        if isinstance(camera, str) and camera not in CAMERAS:
            raise UserError(f"render: camera {camera!r} is not one of {', '.join(CAMERAS)}")
        self.pyrender = pyrender = import_pyrender()
        from OpenGL import GL

        self._gl = GL
        self.width, self.height = int(width), int(height)
        if rig is None:
            from convodrive.backends.avatar.mannequin import build_mannequin

            rig = build_mannequin()
        self.rig = rig
        self.poser = RigPoser(rig)
        self.scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[0.20, 0.20, 0.22])
        self._primitives: list[tuple[Any, int, int, np.ndarray]] = []
        self.scene.add(pyrender.Mesh([self._primitive(surface) for surface in rig.surfaces]))
        preset = CAMERAS[camera] if isinstance(camera, str) else camera
        self.camera = pyrender.PerspectiveCamera(
            yfov=math.radians(preset.yfov_deg), aspectRatio=self.width / self.height, znear=0.05, zfar=30.0
        )
        self.camera_pose = camera_pose(preset, rig, self.width / self.height)
        self.scene.add(self.camera, pose=self.camera_pose)
        target = frame_target(preset, rig)[0]
        for color, intensity, where in (
            ((1.0, 0.96, 0.90), 3.2, (1.6, 2.4, 2.6)),  # key: front left, high
            ((0.85, 0.90, 1.0), 1.3, (-2.2, 1.2, 2.0)),  # fill: front right, low
            ((1.0, 1.0, 1.0), 2.6, (-0.8, 2.6, -2.5)),
        ):  # rim: behind
            light = pyrender.DirectionalLight(color=np.array(color), intensity=intensity)
            self.scene.add(light, pose=look_at(target + np.array(where), target))
        backdrop, world = backdrop_image(self.width, self.height, self.camera, self.camera_pose)
        self._backdrop = backdrop
        self._backdrop_u8 = np.clip(backdrop * 255, 0, 255).astype(np.uint8)
        self._floor_pixels = np.flatnonzero(world[..., 1].ravel() < 0.01)
        self._floor_xz = world.reshape(-1, 3)[self._floor_pixels][:, [0, 2]]
        self.stats = {"frames": 0, "skin_s": 0.0, "gl_s": 0.0}
        try:
            self.renderer = pyrender.OffscreenRenderer(self.width, self.height)
            if lean_shader:
                avatar_shader.install(self.renderer)
            with msaa_samples(4 if antialias else 0):
                self.renderer.render(self.scene)  # allocates the framebuffer
        except Exception as exc:  # a platform that probed fine but cannot open this size
            raise UserError(f"render: cannot open a {self.width}x{self.height} offscreen GL context: {exc}") from None

    def _primitive(self, surface: Surface) -> Any:
        """A pyrender primitive for one surface, remembered with the vertex buffer ``_upload`` rewrites.

        Our shader reads pyrender's ``metallic_factor`` as the skin scatter (it draws no metals)
        and ``emissive_factor.x`` as the alpha cutoff of a masked texture.
        """
        pyrender, rig = self.pyrender, self.rig
        material = rig.materials[surface.material]
        start, end = surface.start, surface.end
        texture = None
        if material.texture is not None and rig.uv is not None:
            texture = pyrender.Texture(
                source=material.texture,
                source_channels="RGBA",
                sampler=pyrender.Sampler(magFilter=9729, minFilter=9987),  # linear, mipmapped
            )
        cutoff = material.alpha_cutoff
        pbr = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=list(material.color),
            baseColorTexture=texture,
            metallicFactor=material.scatter,
            roughnessFactor=material.roughness,
            emissiveFactor=[cutoff if cutoff is not None else -1.0, 0.0, 0.0],
            alphaMode="BLEND" if cutoff is not None else "OPAQUE",
            doubleSided=material.double_sided,
        )
        colors = rig.colors[start:end]
        uv = rig.uv[start:end] if texture is not None and rig.uv is not None else None
        prim = pyrender.Primitive(
            positions=rig.rest[start:end],
            normals=rig.normals[start:end],
            texcoord_0=uv,
            color_0=colors,
            indices=surface.faces,
            material=pbr,
        )
        columns = [rig.rest[start:end], rig.normals[start:end]] + ([uv] if uv is not None else []) + [colors]
        self._primitives.append((prim, start, end, np.hstack(columns).astype(np.float32)))
        return prim

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

    def _composite(self, rgba: np.ndarray, root: np.ndarray) -> np.ndarray:
        """Avatar over the backdrop (by coverage alpha), with a soft contact shadow under the root.

        Only pixels the avatar touches are blended in float; the rest is a copy of the backdrop.
        """
        out = self._backdrop_u8.copy()
        if len(self._floor_pixels):
            d = self._floor_xz - root[[0, 2]]
            shade = 1.0 - 0.45 * np.exp(-((d[:, 0] / 0.32) ** 2 + (d[:, 1] / 0.24) ** 2))
            flat = out.reshape(-1, 3)
            flat[self._floor_pixels] = (
                self._backdrop.reshape(-1, 3)[self._floor_pixels] * 255 * shade[:, None]
            ).astype(np.uint8)
        alpha = rgba[..., 3]
        full = alpha == 255
        out[full] = rgba[..., :3][full]
        edge = (alpha > 0) & ~full
        if edge.any():  # MSAA edges resolve to premultiplied colour
            a = alpha[edge].astype(np.float32)[:, None] / 255.0
            out[edge] = np.clip(rgba[..., :3][edge] + out[edge] * (1.0 - a), 0, 255).astype(np.uint8)
        return out

    def render(self, frame: MotionFrame) -> np.ndarray:
        """One (H, W, 3) uint8 image of the avatar in ``frame``'s pose."""
        t0 = time.perf_counter()
        verts, normals = self.poser.pose(frame)
        t1 = time.perf_counter()
        self._upload(verts, normals)
        rgba, depth = self.renderer.render(self.scene, flags=self.pyrender.RenderFlags.RGBA)
        if rgba.shape[-1] == 3:  # OSMesa draws to its own buffer and returns RGB: coverage from depth
            rgba = np.dstack([rgba, np.where(depth > 0, 255, 0).astype(np.uint8)])
        image = self._composite(
            rgba, self.rig.landmarks["pelvis"] + self.poser.translation_scale * np.asarray(frame.translation, float)
        )
        self.stats["skin_s"] += t1 - t0
        self.stats["gl_s"] += time.perf_counter() - t1
        self.stats["frames"] += 1
        return image

    def render_takes(self, takes: Sequence[MotionFrame]) -> np.ndarray:
        """The takes tiled in a grid (``grid_shape``), each tile W x H."""
        if len(takes) == 1:
            return self.render(takes[0])
        rows, cols = grid_shape(len(takes))
        canvas = np.empty((rows * self.height, cols * self.width, 3), np.uint8)
        canvas[:] = (np.array(BACKGROUND) * 200).astype(np.uint8)
        for i, frame in enumerate(takes):
            r, c = divmod(i, cols)
            canvas[r * self.height : (r + 1) * self.height, c * self.width : (c + 1) * self.width] = self.render(frame)
        return canvas

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel (x, y) of world points in a tile, rows counted from the top."""
        pts = np.atleast_2d(np.asarray(points, float))
        proj = self.camera.get_projection_matrix(self.width, self.height) @ np.linalg.inv(self.camera_pose)
        p = np.concatenate([pts, np.ones((len(pts), 1))], 1) @ proj.T
        ndc = p[:, :3] / p[:, 3:4]
        return np.stack([(ndc[:, 0] + 1) / 2 * self.width, (1 - ndc[:, 1]) / 2 * self.height], 1)

    def close(self) -> None:
        if getattr(self, "renderer", None) is not None:
            delete_offscreen(self.renderer)
            self.renderer = None
