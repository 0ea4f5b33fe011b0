"""Backend ``render``: the mesh avatar filmed headless into an mp4 with the session's audio.

It consumes canonical motion (``frame.takes``: one take, or K takes of the same audio laid out
side by side), poses the built-in mannequin or the user's glTF/VRM avatar, renders offscreen
(EGL, else OSMesa) and writes ``avatar.mp4`` (H.264, yuv420p, 30 fps, audio muxed) plus
``avatar_contact.png``, a contact sheet of evenly spaced frames labelled with who is talking.
With ``window: true`` and a display it also shows the frames live; it is then a real-time
backend, which skips the frames it cannot render in time, and the video keeps its timeline by
repeating the last image for each skipped frame (counted in the report, which then says degraded).

Options: ``RenderOptions`` below (``convodrive plugins render`` lists them); ``avatar`` names a
.glb/.gltf/.vrm avatar (or a YAML name map for one) to show instead of the mannequin.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.backends.avatar.render_scene import CAMERAS, AvatarRenderer, grid_shape, parse_resolution
from convodrive.backends.avatar.rig import Rig
from convodrive.backends.base import Backend, Session
from convodrive.motion.channels import ConversationState
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, check_file_name, option
from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.errors import UserError

MAX_VIDEO_SIDE = 8192
"""Widest or tallest video the grid of takes may make (H.264's largest frames)."""
log = logging.getLogger(__name__)

CONTACT_CELLS = 12
CONTACT_COLUMNS = 4
THUMB_WIDTH = 320
STATE_COLORS = {
    ConversationState.SPEAKING: (30, 130, 60),
    ConversationState.LISTENING: (40, 90, 170),
    ConversationState.OVERLAP: (190, 110, 20),
    ConversationState.SILENCE: (90, 90, 90),
}
"""Label colours on the contact sheet: who is talking in that frame."""


class ContactSheet:
    """Evenly spaced thumbnails of a stream of unknown length, in bounded memory.

    Keeps every ``stride``-th frame; when the buffer passes twice the sheet's cells, every other
    thumbnail is dropped and the stride doubles, so the kept frames stay evenly spread.
    """

    def __init__(self, cells: int = CONTACT_CELLS) -> None:
        self.cells = cells
        self.stride = 1
        self.kept: list[tuple[int, np.ndarray, ConversationState]] = []

    def offer(self, index: int, image: np.ndarray, state: ConversationState = ConversationState.SILENCE) -> None:
        if index % self.stride:
            return
        from PIL import Image

        h, w = image.shape[:2]
        scale = THUMB_WIDTH / w
        thumb = np.asarray(Image.fromarray(image).resize((THUMB_WIDTH, max(2, round(h * scale))), Image.BILINEAR))
        self.kept.append((index, thumb, ConversationState(state)))
        if len(self.kept) > 2 * self.cells:
            self.kept = self.kept[::2]
            self.stride *= 2

    def write(self, path: Path, fps: float) -> Path | None:
        if not self.kept:
            return None
        from PIL import Image, ImageDraw

        pick = np.unique(np.linspace(0, len(self.kept) - 1, min(self.cells, len(self.kept))).round().astype(int))
        thumbs = [self.kept[i] for i in pick]
        th, tw = thumbs[0][1].shape[:2]
        cols = min(CONTACT_COLUMNS, len(thumbs))
        rows = -(-len(thumbs) // cols)
        pad = 6
        sheet = Image.new("RGB", (cols * (tw + pad) + pad, rows * (th + pad) + pad), (32, 34, 38))
        draw = ImageDraw.Draw(sheet)
        for k, (index, thumb, state) in enumerate(thumbs):
            x, y = pad + (k % cols) * (tw + pad), pad + (k // cols) * (th + pad)
            sheet.paste(Image.fromarray(thumb), (x, y))
            label = f"{index / fps:6.2f} s"
            draw.rectangle((x, y + th - 16, x + 62, y + th), fill=(0, 0, 0))
            draw.text((x + 4, y + th - 14), label, fill=(240, 240, 240))
            name = state.name.lower()
            width = 8 + 6 * len(name)
            draw.rectangle((x + tw - width, y + th - 16, x + tw, y + th), fill=STATE_COLORS[state])
            draw.text((x + tw - width + 4, y + th - 14), name, fill=(255, 255, 255))
        with atomic_path(path) as tmp:
            sheet.save(tmp, format="PNG")
        return path


class Captions:
    """Each take's caption in its tile's top-left corner: drawn once with PIL, then blended into
    every frame with NumPy (a mask and a colour), so captions cost no PIL work per frame."""

    def __init__(self, labels: Sequence[str], tile_width: int, tile_height: int, shape: tuple[int, ...]) -> None:
        from PIL import Image, ImageDraw, ImageFont

        font = ImageFont.load_default(size=max(12, tile_height // 24))
        layer = Image.new("RGBA", (shape[1], shape[0]), (0, 0, 0, 0))
        draw = ImageDraw.Draw(layer)
        cols = max(shape[1] // tile_width, 1)
        for k, text in enumerate(labels):
            if not text:
                continue
            x, y = (k % cols) * tile_width + 8, (k // cols) * tile_height + 8
            left, top, right, bottom = draw.textbbox((x, y), text, font=font)
            draw.rectangle((left - 5, top - 4, right + 5, bottom + 4), fill=(0, 0, 0, 170))
            draw.text((x, y), text, font=font, fill=(255, 255, 255, 255))
        rgba = np.asarray(layer, np.float32) / 255.0
        self.alpha = rgba[..., 3:4]
        self.colour = rgba[..., :3] * 255.0 * self.alpha

    def draw(self, image: np.ndarray) -> np.ndarray:
        return (image * (1.0 - self.alpha) + self.colour).astype(np.uint8)


def display_available() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@dataclasses.dataclass(frozen=True)
class RenderOptions(PluginOptions):
    camera: str = option("upper", choices=tuple(CAMERAS), help="Camera preset framing the avatar")
    resolution: str = option("512x512", help="Size of each take, WIDTHxHEIGHT, even numbers from 16 to 4096")
    filename: str = option("avatar.mp4", help="Video file name in the output folder (.mp4)")
    contact_sheet: str | bool = option(
        "avatar_contact.png", help="File name of the PNG contact sheet, or false for none"
    )
    antialias: bool = option(False, help="4x multisampling (about 2.5x slower on software GL)")
    window: bool = option(False, help="Also show the frames in a live window when a display exists")
    avatar: str = option(
        "", help="A .glb, .gltf or .vrm avatar, or a YAML name map for one; empty for the built-in mannequin"
    )
    labels: str = option("", help="Captions of the takes, comma separated, drawn in each take's top-left corner")

    def __post_init__(self) -> None:
        try:
            parse_resolution(self.resolution)
        except UserError as exc:
            raise ValueError(f"option {exc}") from None
        check_file_name("filename", self.filename, ".mp4")
        if self.contact_sheet is True:
            raise ValueError("option 'contact_sheet' takes a file name or false, got true")
        if self.contact_sheet:
            check_file_name("contact_sheet", str(self.contact_sheet), ".png")


class RenderBackend(Backend):
    name = "render"
    description = "Mesh avatar preview: headless pyrender (EGL/OSMesa) to mp4 with audio, K takes in a grid"
    realtime = False
    may_run_in_process = True
    default_profile = None
    requires = ("pyrender", "OpenGL", "trimesh")
    extra = "render"
    Options = RenderOptions
    options: RenderOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.camera = self.options.camera
        self.width, self.height = parse_resolution(self.options.resolution)
        self.filename = self.options.filename
        self.sheet_name = str(self.options.contact_sheet) if self.options.contact_sheet else None
        self.antialias = self.options.antialias
        self.want_window = self.options.window
        self.avatar_path = self.options.avatar
        self.labels = [text.strip() for text in self.options.labels.split(",")] if self.options.labels else []
        self._captions: Captions | None = None
        self.window_note = None
        if self.want_window and display_available():
            self.realtime = True  # type: ignore[misc]  # a live window is paced by the wall clock
        elif self.want_window:
            self.window_note = "window requested but no display (DISPLAY unset): rendering to file only"
            log.warning("render: %s", self.window_note)
        self._renderer: AvatarRenderer | None = None
        self._rig: Rig | None = None
        self._writer: Any = None
        self._window: Any = None
        self._sheet = ContactSheet()
        self._outputs: list[Path] = []
        self._frames = 0
        self._repeated = 0
        self._next_index = 0
        self._last_image: np.ndarray | None = None
        self._takes = 0
        self._errors: list[str] = []
        self._wall = 0.0
        self._renderer_stats: dict[str, float] = {"frames": 0, "skin_s": 0.0, "gl_s": 0.0}

    def open(self, spec: TargetSpec, session: Session) -> None:
        """Check that headless GL works and load the avatar (a bad avatar file fails here, before
        any frame); the GL context itself is made on the first ``send``, because an EGL context
        belongs to the thread that made it current and the scheduler opens backends on one thread
        and feeds them on another."""
        from convodrive.backends.avatar.pyrender_gl import select_platform

        super().open(spec, session)
        rows, cols = grid_shape(session.num_samples)
        if max(cols * self.width, rows * self.height) > MAX_VIDEO_SIDE:
            raise UserError(
                f"backend render: {session.num_samples} takes of {self.options.resolution} make a "
                f"{cols * self.width}x{rows * self.height} video; the most is {MAX_VIDEO_SIDE} a side "
                "(lower the resolution or the takes)"
            )
        self.out_dir = Path(session.out_dir)
        self.video_path = self.out_dir / self.filename
        select_platform()
        if self.avatar_path:
            from convodrive.backends.avatar.gltf_read import load_avatar

            self._rig = load_avatar(Path(self.avatar_path).expanduser())
        else:
            from convodrive.backends.avatar.mannequin import build_mannequin

            self._rig = build_mannequin()

    def _start(self) -> None:
        self._renderer = AvatarRenderer(self.width, self.height, self.camera, antialias=self.antialias, rig=self._rig)
        if self.realtime:
            try:
                from convodrive.backends.avatar.live_window import LiveWindow

                self._window = LiveWindow("convodrive avatar")
            except Exception as exc:  # no Tk, display refused: keep the file output
                self.window_note = f"live window unavailable ({exc}); rendering to file only"
                log.warning("render: %s", self.window_note)

    def _open_writer(self, takes: int) -> None:
        from convodrive.plumbing.video import VideoWriter

        rows, cols = grid_shape(takes)
        audio = self.session.audio_path if self.session else None
        self._writer = VideoWriter(
            self.video_path,
            cols * self.width,
            rows * self.height,
            fps=self.session.fps if self.session else 30,
            audio_path=audio,
        )
        self._takes = takes

    def send(self, frame: TargetFrame) -> None:
        if self.session is None:
            raise RuntimeError("render: send() before open()")
        t0 = time.perf_counter()
        if self._renderer is None:
            self._start()
        assert self._renderer is not None
        takes = frame.takes
        if self._writer is None:
            self._open_writer(len(takes))
        if len(takes) != self._takes:  # keep the grid: pad with the first take or drop extras
            takes = (tuple(takes) + (takes[0],) * self._takes)[: self._takes]
        image = self._renderer.render_takes(takes)
        if self.labels:
            if self._captions is None:
                self._captions = Captions(self.labels, self.width, self.height, image.shape)
            image = self._captions.draw(image)
        # Frames skipped in real time still take their place in the video, so it stays as long
        # as the audio and in step with it: the image before the gap stands in for them.
        for _ in range(max(frame.index - self._next_index, 0)):
            self._writer.append(self._last_image if self._last_image is not None else image)
            self._repeated += 1
        self._next_index = frame.index + 1
        self._last_image = image
        self._writer.append(image)
        self._sheet.offer(frame.index, image, takes[0].state)
        if self._window is not None:
            try:
                self._window.show(image)
            except Exception as exc:  # window closed by the user: keep filming
                self.window_note = f"live window closed ({exc})"
                log.warning("render: %s", self.window_note)
                self._window = None
        self._frames += 1
        self._wall += time.perf_counter() - t0

    def close(self) -> None:
        if self._writer is not None:
            try:
                self._outputs.append(self._writer.close())
            except Exception as exc:
                self._errors.append(f"video: {exc}")
                self._writer.abort()
            self._writer = None
            if self.sheet_name:
                fps = self.session.fps if self.session else 30
                sheet = self._sheet.write(self.out_dir / self.sheet_name, fps)
                if sheet:
                    self._outputs.append(sheet)
        if self._window is not None:
            self._window.close()
            self._window = None
        if self._renderer is not None:
            self._renderer_stats = dict(self._renderer.stats)
            try:  # the outputs are complete already; a GL teardown fault must not mask them
                self._renderer.close()
            except Exception as exc:
                self._errors.append(f"gl teardown: {exc.__class__.__name__}")
            self._renderer = None

    def abort(self) -> None:
        """Drop the partial video (for callers that stop on an error and want no output)."""
        if self._writer is not None:
            self._writer.abort()
            self._writer = None

    def health(self) -> dict[str, Any]:
        reasons = list(self._errors)
        if self.window_note:
            reasons.append(self.window_note)
        if self._repeated:
            total = self._frames + self._repeated
            reasons.append(
                f"the video repeats the previous image for {self._repeated} of {total} frames "
                "(rendering fell behind the live window)"
            )
        out: dict[str, Any] = {"status": "degraded" if reasons else "ok", "frames": self._frames}
        if reasons:
            out["reason"] = "; ".join(reasons)
        if self.window_note:
            out["note"] = self.window_note
        return out

    def report(self) -> dict[str, Any]:
        from convodrive.backends.avatar.pyrender_gl import select_platform

        stats = self._renderer.stats if self._renderer else self._renderer_stats
        rows, cols = grid_shape(max(self._takes, 1))
        renders = max(stats["frames"], 1)
        out: dict[str, Any] = {
            "outputs": [str(p) for p in self._outputs],
            "frames": self._frames,
            "frames_repeated": self._repeated,
            "takes": self._takes,
            "grid": [rows, cols],
            "camera": self.camera,
            "resolution": [cols * self.width, rows * self.height],
            "gl_platform": select_platform() if self.session else None,
            "antialias": self.antialias,
            "avatar": self.avatar_path or "mannequin",
            "render_fps": round(self._frames / self._wall, 2) if self._wall else None,
            "skin_ms_per_take": round(1000 * stats["skin_s"] / renders, 3),
            "gl_ms_per_take": round(1000 * stats["gl_s"] / renders, 3),
            "errors": self._errors,
        }
        if self.window_note:
            out["note"] = self.window_note
        return out

    def outputs(self) -> list[Path]:
        return list(self._outputs)
