"""What a live session measures of itself, frame by frame, and the figures it makes of that.

- latencies: a partner sample's capture to its frame generated, dispatched and sent to each
  backend, and the agent's voice fed to sent (what a framework's TTS chunk costs);
- the mouth: each frame's jawOpen and dispatch time, the self voice's level, and (with a monitor
  hearing the speaker) the audio–motion offset heard there, and ``sync.npz``, its evidence.
"""

from __future__ import annotations

import array
import collections
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.audio.live.capture import Recording
from convodrive.audio.source import ANALYSIS_RATE, AudioChunk
from convodrive.eval.sync import LevelMeter, level_db, mouth_onsets, pair_onsets, speech_onsets
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.clip import MotionFrame
from convodrive.motion.targets import TargetFrame
from convodrive.plumbing.atomic import atomic_path
from convodrive.plumbing.stats import Histogram


class Measures:
    """Hooks the run calls (``chunks``, ``frames_of``, ``dispatched``, ``sent``) and the figures."""

    def __init__(self) -> None:
        self.frame_capture: dict[int, float] = {}
        """Frame index -> monotonic capture time of its first partner sample (``LiveAudio``'s)."""
        self.backends = 1
        self.fed: dict[int, float] = {}
        """Frame index -> monotonic time the agent's voice it plays was fed."""
        self.frames: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=FPS * 600)
        """(frame index, monotonic dispatch time, jawOpen) of the last ten minutes' frames."""
        self.jaw = array.array("d")
        self.dispatch = array.array("d")
        self.level = LevelMeter(ANALYSIS_RATE)
        self._generated: dict[int, float] = {}
        self.capture_to_generated = Histogram()
        self.generated_to_dispatched = Histogram()
        self.capture_to_sent: dict[str, Histogram] = {}
        self.fed_to_sent: dict[str, Histogram] = {}

    # -- the run's hooks ------------------------------------------------------------------------
    def chunks(self, chunks: Iterator[AudioChunk]) -> Iterator[AudioChunk]:
        for chunk in chunks:
            self.level.push(chunk.self_voice)
            yield chunk

    def frames_of(self, takes: Iterator[tuple[MotionFrame, ...]]) -> Iterator[tuple[MotionFrame, ...]]:
        """The generator's frames, noting when each was made and how open its mouth is."""
        jaw = BLENDSHAPE_INDEX["jawOpen"]
        for index, frame in enumerate(takes):
            now = time.monotonic()
            self._generated[index] = now
            self._generated.pop(index - 300, None)
            self.jaw.append(float(frame[0].face[jaw]))
            captured = self.frame_capture.get(index)
            if captured is not None:
                self.capture_to_generated.add(1000.0 * (now - captured))
            yield frame

    def dispatched(self, index: int) -> None:
        now = time.monotonic()
        self.dispatch.append(now)
        self.frames.append((index, now, self.jaw[index] if index < len(self.jaw) else 0.0))
        made = self._generated.get(index)
        if made is not None:
            self.generated_to_dispatched.add(1000.0 * (now - made))

    def fed_at(self, index: int, mono: float) -> None:
        """The voice of frame ``index`` was fed at ``mono`` (the first feeding counts)."""
        self.fed.setdefault(index, mono)

    def sent(self, backend: str, frame: TargetFrame, done: float) -> None:
        fed = self.fed.pop(frame.index, None) if self.backends == 1 else self.fed.get(frame.index)
        if fed is not None:
            self.fed_to_sent.setdefault(backend, Histogram()).add(1000.0 * (done - fed))
        captured = self.frame_capture.get(frame.index)
        if captured is not None:
            self.capture_to_sent.setdefault(backend, Histogram()).add(1000.0 * (done - captured))

    # -- figures --------------------------------------------------------------------------------
    def latency(self) -> dict[str, Any]:
        return {
            "partner_capture_to_generated": self.capture_to_generated.summary(),
            "generated_to_dispatched": self.generated_to_dispatched.summary(),
            "partner_capture_to_sent": {k: h.summary() for k, h in self.capture_to_sent.items()},
            "self_fed_to_sent": {k: h.summary() for k, h in self.fed_to_sent.items()},
        }

    def offsets(self, monitor: Recording | None, name: str) -> tuple[dict[str, Any], dict[str, Any]]:
        """The audio–motion offset heard at the monitor (``name``: how to ask for one), and the
        generator's own offset (its mouth against the voice it was given)."""
        jaw = np.asarray(self.jaw)
        dispatch = np.asarray(self.dispatch)
        n = min(len(jaw), len(dispatch))
        own = pair_onsets(speech_onsets(self.level.db), mouth_onsets(jaw) / FPS).summary()
        if monitor is None:
            return {"measured": False, "why": f"give {name} DEVICE (a capture of the speaker) to measure it"}, own
        recording = monitor.samples()
        db = level_db(recording, ANALYSIS_RATE)
        audio_mono = monitor.mono_at((speech_onsets(db) * ANALYSIS_RATE).astype(np.int64))
        motion_mono = dispatch[mouth_onsets(jaw[:n])] if n else np.zeros(0)
        heard = pair_onsets(audio_mono, motion_mono).summary()
        heard["measured"] = True
        heard["monitor_seconds"] = round(len(recording) / ANALYSIS_RATE, 3)
        return heard, own

    def write_evidence(self, monitor: Recording | None, out_dir: Path) -> list[Path]:
        """``sync.npz``: per-frame dispatch times and mouth opening, the monitor recording and its
        capture times, the self voice's levels: everything the offset figures come from."""
        if monitor is None:
            return []
        recording = monitor.samples()
        index = np.arange(0, len(recording), ANALYSIS_RATE // 10)
        path = out_dir / "sync.npz"
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(
                    fh,
                    frame_dispatch_mono=np.asarray(self.dispatch),
                    jaw_open=np.asarray(self.jaw, np.float32),
                    monitor=np.clip(recording * 32767.0, -32768, 32767).astype(np.int16),
                    monitor_rate=np.int64(ANALYSIS_RATE),
                    monitor_index=index,
                    monitor_mono=monitor.mono_at(index),
                    self_level_db=self.level.db.astype(np.float32),
                )
        return [path]
