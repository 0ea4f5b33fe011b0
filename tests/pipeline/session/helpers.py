"""What the live-session tests share: a voice, a fake speaker that reports what it played, and
reading the motion a session made."""

from __future__ import annotations

import functools
import threading
import time

import numpy as np

from convodrive.audio.source import ANALYSIS_RATE
from convodrive.pipeline.session import Event, LiveSession

CLOSED = 0.05
"""jawOpen below this is a closed mouth."""
CHUNK = 0.04
"""The fake speakers' chunk: Pipecat's 40 ms."""


@functools.lru_cache(maxsize=2)
def voice(
    text: str = "Well, the train leaves at nine, and then we walk along the river to the old bridge.",
) -> np.ndarray:
    """Speech at 16 kHz (espeak-ng), as int16."""
    from convodrive.audio.synth import speak

    return (np.clip(speak(text, sample_rate=ANALYSIS_RATE), -1, 1) * 32767).astype(np.int16)


def feed_silence(session: LiveSession, seconds: float, stop: threading.Event) -> threading.Thread:
    """The partner's microphone: 20 ms of silence every 20 ms, until ``stop``."""

    def run() -> None:
        block = np.zeros(int(0.02 * ANALYSIS_RATE), np.int16)
        t0 = time.monotonic()
        n = 0
        while not stop.is_set() and n * 0.02 < seconds:
            session.feed_partner(block.tobytes(), ANALYSIS_RATE, at=t0 + n * 0.02)
            n += 1
            time.sleep(max(t0 + (n + 1) * 0.02 - time.monotonic(), 0))

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def mouth(session: LiveSession) -> tuple[np.ndarray, np.ndarray]:
    """(monotonic dispatch times, jawOpen) of the frames the session handed out."""
    frames = list(session.frames)
    return np.array([f[1] for f in frames]), np.array([f[2] for f in frames])


def onset(times: np.ndarray, jaw: np.ndarray, after: float, level: float = 0.15) -> float | None:
    """The first dispatch time after ``after`` at which the mouth is open past ``level``."""
    open_ = np.nonzero((times > after) & (jaw > level))[0]
    return float(times[open_[0]]) if len(open_) else None


def kinds(session: LiveSession) -> list[Event]:
    """The kinds of events the session sent, repeats folded."""
    out: list[Event] = []
    for _, e in session.events:
        if not out or out[-1] is not e.kind:
            out.append(e.kind)
    return out


def told_at(session: LiveSession, kind: Event) -> float:
    """When (monotonic) the session was last told ``kind``: for ``INTERRUPTED``, when the framework's
    interruption reached it, which a busy event loop may deliver well after it was raised."""
    return [t for t, e in session.events if e.kind is kind][-1]


def eye_angle(out_dir) -> np.ndarray:
    """Degrees the left eye turned, per frame of the recorder's motion.npz in ``out_dir``."""
    from convodrive.motion.npz import load_clip
    from convodrive.motion.skeleton import JOINT_INDEX as J

    clip = load_clip(out_dir / "motion.npz")
    return np.degrees(np.linalg.norm(clip.pose[:, J["left_eye_smplhf"]], axis=1))
