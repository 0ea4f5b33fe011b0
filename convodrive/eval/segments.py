"""Reference speech segments: who really spoke when, from a file the user has.

The behaviour eval otherwise finds speech with a level detector of its own, which is fooled by
the same things as the generator's (a partner heard through self's microphone). Two formats:

- JSON: a list of segments, or an object with a ``turns`` or ``segments`` list (the sidecar that
  ``samples/make_dialogue.py`` and ``audio.synth`` write). Each segment has ``start`` and ``end`` in
  seconds and ``speaker`` (``self`` or ``partner``) or ``channel`` (a channel number of the audio).
- Audacity labels (``.txt``): ``START<TAB>END<TAB>LABEL`` lines, the label ``self`` or ``partner``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.plumbing.errors import InputFileError
from convodrive.plumbing.text import clip_value

SPEAKERS = ("self", "partner")
_ALIASES = {"self": "self", "partner": "partner", "other": "partner"}


@dataclasses.dataclass(frozen=True)
class Segments:
    """Speech intervals (start, end) in seconds of each speaker."""

    self_speech: tuple[tuple[float, float], ...]
    partner_speech: tuple[tuple[float, float], ...]
    source: str = ""

    def masks(self, num_frames: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
        """(self, partner) boolean masks of the frames that hold any of a segment: a frame where a
        voice starts or stops counts as speech, so "silent" frames are wholly silent."""
        starts = np.arange(num_frames) / fps
        return _mask(self.self_speech, starts, 1.0 / fps), _mask(self.partner_speech, starts, 1.0 / fps)


def _mask(intervals: tuple[tuple[float, float], ...], starts: np.ndarray, length: float) -> np.ndarray:
    out = np.zeros(len(starts), bool)
    for start, end in intervals:
        out |= (starts < end) & (starts + length > start)
    return out


def load_segments(path: str | Path, self_channel: int = 0, other_channel: int | None = 1) -> Segments:
    """Read a JSON or Audacity label file; a channel number maps through the audio's channel choice."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such file" if not path.exists() else "is not a file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read speech segments ({exc.__class__.__name__})") from None
    if text.lstrip().startswith(("{", "[")):
        items = _json_items(path, text)
    else:
        items = _audacity_items(path, text)
    channels = {self_channel: "self", other_channel: "partner"}
    spans: dict[str, list[tuple[float, float]]] = {"self": [], "partner": []}
    for where, item in items:
        speaker = _speaker(path, where, item, channels)
        if speaker is None:
            continue
        start, end = _time(path, where, item, "start"), _time(path, where, item, "end")
        if end < start:
            raise InputFileError(path, f"{where}: end {end:g} s is before start {start:g} s")
        spans[speaker].append((start, end))
    if not spans["self"] and not spans["partner"]:
        raise InputFileError(path, "holds no speech segments of self or the partner")
    return Segments(tuple(sorted(spans["self"])), tuple(sorted(spans["partner"])), str(path))


def _json_items(path: Path, text: str) -> list[tuple[str, dict[str, Any]]]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputFileError(path, f"not valid JSON (line {exc.lineno}: {exc.msg})") from None
    if isinstance(data, dict):
        key = "turns" if "turns" in data else "segments"
        data = data.get(key)
        if data is None:
            raise InputFileError(path, 'JSON speech segments need a "turns" or "segments" list')
    if not isinstance(data, list):
        raise InputFileError(path, "JSON speech segments must be a list")
    items = []
    for i, item in enumerate(data):
        if not isinstance(item, dict):
            raise InputFileError(path, f"segment {i} must be an object with start, end and speaker")
        items.append((f"segment {i}", item))
    return items


def _audacity_items(path: Path, text: str) -> list[tuple[str, dict[str, Any]]]:
    items = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.startswith("\\"):  # Audacity's spectral-selection lines start with "\"
            continue
        fields = line.split("\t")
        if len(fields) < 3:
            raise InputFileError(path, f"line {number}: expected START<TAB>END<TAB>LABEL (Audacity labels) or JSON")
        items.append((f"line {number}", {"start": fields[0], "end": fields[1], "speaker": fields[2].strip()}))
    return items


def _speaker(path: Path, where: str, item: dict[str, Any], channels: dict[int | None, str]) -> str | None:
    if "speaker" in item:
        name = _ALIASES.get(str(item["speaker"]).strip().lower())
        if name is None:
            raise InputFileError(path, f"{where}: speaker {clip_value(item['speaker'])} is not self or partner")
        return name
    if "channel" in item:
        try:
            return channels.get(int(item["channel"]))
        except (TypeError, ValueError):
            raise InputFileError(path, f"{where}: channel {clip_value(item['channel'])} is not a number") from None
    raise InputFileError(path, f"{where}: needs a speaker (self or partner) or a channel number")


def _time(path: Path, where: str, item: dict[str, Any], key: str) -> float:
    if key not in item:
        raise InputFileError(path, f"{where}: missing {key}")
    try:
        value = float(item[key])
    except (TypeError, ValueError):
        raise InputFileError(path, f"{where}: {key} {clip_value(item[key])} is not a number of seconds") from None
    if not math.isfinite(value) or value < 0:
        raise InputFileError(path, f"{where}: {key} must be a finite, non-negative number of seconds")
    return value
