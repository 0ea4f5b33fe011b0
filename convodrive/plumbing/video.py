"""Video files: H.264 yuv420p mp4 at 30 fps with the session audio muxed, written atomically.

Every backend that films (the renderer, MuJoCo) goes through ``VideoWriter``, so all videos share
one encoder setup. ffmpeg comes from imageio-ffmpeg's bundled binary: nothing to install.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from convodrive import FPS


def ffmpeg_exe() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


class VideoWriter:
    """Append RGB frames; ``close`` muxes the audio and renames the file into place.

    The video keeps its own length (no ``-shortest``): a run produces one frame per 1/30 s of
    audio, so the two streams end within a frame of each other. ``abort`` discards the output.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        width: int,
        height: int,
        fps: float = FPS,
        audio_path: str | os.PathLike[str] | None = None,
        quality: int = 7,
    ) -> None:
        import imageio_ffmpeg

        if width % 2 or height % 2:
            raise ValueError(f"yuv420p needs even frame sizes, got {width}x{height}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.size = (int(width), int(height))
        self.frames_written = 0
        self._tmp = self.path.with_name(f".{self.path.stem}.partial{self.path.suffix}")
        output_params = ["-movflags", "+faststart", "-profile:v", "high"]
        self._writer: Any = imageio_ffmpeg.write_frames(
            str(self._tmp),
            self.size,
            fps=fps,
            codec="libx264",
            pix_fmt_out="yuv420p",
            quality=quality,
            macro_block_size=2,
            output_params=output_params,
            ffmpeg_log_level="error",
            audio_path=str(audio_path) if audio_path else None,
            audio_codec="aac" if audio_path else None,
        )
        self._writer.send(None)  # start the generator: ffmpeg launches here

    def append(self, rgb: np.ndarray) -> None:
        if rgb.shape != (self.size[1], self.size[0], 3):
            raise ValueError(f"frame shape {rgb.shape} does not match video size {self.size}")
        self._writer.send(np.ascontiguousarray(rgb, dtype=np.uint8))
        self.frames_written += 1

    def close(self) -> Path:
        self._writer.close()
        os.replace(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        try:
            self._writer.close()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
