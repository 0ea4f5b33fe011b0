"""Bundled sample data, installed as ``convodrive.samples``.

``dialogue.wav`` is a 25 s two-speaker espeak-ng dialogue (self on channel 0, the partner on
channel 1, with turns, pauses and overlaps), made by ``make_dialogue.py`` in this folder; the turn
timings are in ``dialogue.json`` beside it in the source tree.
"""

from __future__ import annotations

from importlib.resources import as_file, files
from pathlib import Path


def bundled_dialogue() -> Path:
    """Path of the bundled dialogue WAV (a real file on disk, also from an installed wheel)."""
    resource = files("convodrive.samples").joinpath("dialogue.wav")
    with as_file(resource) as path:  # a no-op for a normal install; zip installs are not supported
        return Path(path)
