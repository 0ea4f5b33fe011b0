"""M4A/AAC input through the ffmpeg command line: probed with ffprobe, decoded as a pipe.

libsndfile reads WAV, FLAC, OGG and MP3 but not AAC, which phones and most recorders write. Here
ffprobe checks the file and ffmpeg decodes it to 32-bit float PCM on a pipe that the reader drains
block by block, so a long recording streams in constant memory like the other formats.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import tempfile
from pathlib import Path
from types import TracebackType

import numpy as np

from convodrive.plumbing.errors import InputFileError

_MESSAGE_CHARS = 160


def clip_line(text: str) -> str:
    """One line of at most ``_MESSAGE_CHARS`` characters (ffmpeg's messages can be long)."""
    text = " ".join(text.split())
    return text if len(text) <= _MESSAGE_CHARS else text[: _MESSAGE_CHARS - 1] + "…"


CONTAINERS = {"mov,mp4,m4a,3gp,3g2,mj2": "M4A", "aac": "AAC"}
"""ffprobe format names read through ffmpeg, and the name convodrive gives each."""


@dataclasses.dataclass(frozen=True)
class FfmpegInfo:
    format: str
    codec: str
    sample_rate: int
    channels: int
    frames: int
    exact: bool
    """True when the container states the sample count (MP4/M4A); raw AAC only estimates it."""


def _looks_like_aac(path: Path) -> bool:
    """An MP4 container (``ftyp`` box) or an ADTS stream (sync word), by its first bytes or name."""
    try:
        with path.open("rb") as f:
            head = f.read(12)
    except OSError:
        return False
    adts = len(head) >= 2 and head[0] == 0xFF and head[1] & 0xF6 == 0xF0
    return head[4:8] == b"ftyp" or adts or path.suffix.lower() in {".m4a", ".aac", ".mp4"}


def probe(path: Path) -> FfmpegInfo | None:
    """The audio stream of an M4A or AAC file, or None when ffprobe finds no such file."""
    exe = shutil.which("ffprobe")
    if exe is None:
        if _looks_like_aac(path):
            raise InputFileError(
                path, "reading M4A/AAC needs ffprobe and ffmpeg, which are not installed (apt install ffmpeg)"
            )
        return None
    cmd = [exe, "-v", "error", "-select_streams", "a:0", "-show_entries", "format=format_name,duration"]
    cmd += ["-show_entries", "stream=codec_name,sample_rate,channels,duration_ts,time_base", "-of", "json", str(path)]
    try:
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
        data = json.loads(result.stdout or "{}")
    except (OSError, subprocess.TimeoutExpired, json.JSONDecodeError):
        return None
    fmt = CONTAINERS.get(data.get("format", {}).get("format_name", ""))
    streams = data.get("streams") or []
    if result.returncode != 0 or fmt is None or not streams:
        return None
    stream = streams[0]
    try:
        rate, channels = int(stream["sample_rate"]), int(stream["channels"])
    except (KeyError, ValueError):
        return None
    exact = stream.get("time_base") == f"1/{rate}" and str(stream.get("duration_ts", "")).isdigit()
    if exact:
        frames = int(stream["duration_ts"])
    else:
        try:
            frames = int(round(float(data["format"]["duration"]) * rate))
        except (KeyError, ValueError):
            frames = 0
    return FfmpegInfo(fmt, str(stream.get("codec_name", "?")), rate, channels, frames, exact)


class FfmpegReader:
    """Decoded float32 frames of a file's first audio stream, read in blocks from ffmpeg's pipe.

    ``read(n)`` returns ``(m, channels)`` with ``m < n`` only at the end. With ``limit`` set (the
    container's exact sample count) decoding stops there: ffmpeg's AAC decoder emits the last
    frame's padding, which is not part of the recording.
    """

    def __init__(self, path: Path, channels: int, limit: int | None = None, sample_rate: int = 0) -> None:
        exe = shutil.which("ffmpeg")
        if exe is None:
            raise InputFileError(path, "reading M4A/AAC needs ffmpeg, which is not installed (apt install ffmpeg)")
        self.path, self.channels, self._left, self._rate = path, channels, limit, sample_rate
        self._read = 0
        self._stderr = tempfile.TemporaryFile()
        cmd = [exe, "-nostdin", "-v", "error", "-i", str(path), "-map", "0:a:0", "-f", "f32le", "-acodec", "pcm_f32le"]
        self._proc = subprocess.Popen([*cmd, "-"], stdout=subprocess.PIPE, stderr=self._stderr)

    def read(self, n: int) -> np.ndarray:
        if self._left is not None:
            n = min(n, self._left)
        width = 4 * self.channels
        assert self._proc.stdout is not None
        data = self._proc.stdout.read(n * width) if n > 0 else b""
        usable = len(data) // width * width
        frames = np.frombuffer(data[:usable], np.float32).reshape(-1, self.channels)
        self._read += len(frames)
        if self._left is not None:
            self._left -= len(frames)
        if len(frames) < n:
            self._check_end()
        return frames

    def _check_end(self) -> None:
        """At the pipe's end: ffmpeg failed, or stopped short of the length the container states
        (a damaged file: AAC decoding skips what it cannot read and still exits 0)."""
        code = self._proc.wait(timeout=30)
        short = self._left is not None and self._left > 0
        if code == 0 and not short:
            return
        self._stderr.seek(0)
        lines = self._stderr.read().decode("utf-8", "replace").strip().splitlines()
        last = lines[-1].replace(str(self.path), "").strip(" :") if lines else f"exit {code}"
        if short and self._rate:
            total = (self._read + (self._left or 0)) / self._rate
            problem = f"decoding stopped at {self._read / self._rate:.1f} s of {total:.1f} s ({last})"
        else:
            problem = f"ffmpeg could not decode it ({last})"
        raise InputFileError(self.path, clip_line(problem))

    def close(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait()
        if self._proc.stdout is not None:
            self._proc.stdout.close()
        self._stderr.close()

    def __enter__(self) -> FfmpegReader:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()
