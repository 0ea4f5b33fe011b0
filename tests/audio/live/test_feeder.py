"""The self-voice feeder against an interruption: voice it has read and not yet queued when the
cut comes must not be queued after the cut's blank (it would play after the interruption)."""

from __future__ import annotations

import threading

import numpy as np

from convodrive.audio.live.feeder import SelfVoiceFeeder
from convodrive.audio.live.ring import SampleRing
from convodrive.audio.live.self_voice import VoiceSource
from convodrive.audio.live.timeline import Timeline
from convodrive.audio.source import ANALYSIS_RATE

RATE = ANALYSIS_RATE


class SlowHandOver(VoiceSource):
    """Hands over 100 ms of voice, but only after ``go`` (or half a second): the moment between
    the feeder's read and its write into the ring, stretched so a cut can fall into it."""

    describe = "test"

    def __init__(self) -> None:
        self.rate = RATE
        self.taken = threading.Event()
        self.go = threading.Event()

    def read(self, max_samples: int, timeout: float) -> np.ndarray | None:
        if self.taken.is_set():
            return np.zeros(0, np.float32)
        self.taken.set()
        self.go.wait(0.5)
        return np.full(int(0.1 * RATE), 0.5, np.float32)


def test_voice_read_before_a_cut_is_silenced_with_what_was_queued() -> None:
    source = SlowHandOver()
    ring, line = SampleRing(RATE), Timeline()
    feeder = SelfVoiceFeeder(source, ring, RATE, line, heard=lambda: 0, lead=0.01, jitter=0.01, clock_now=lambda: 0.0)
    feeder.start()
    try:
        assert source.taken.wait(5.0)
        cut = int(0.02 * RATE)

        def interrupt() -> None:
            feeder.cut(lambda: cut, lambda _: None)
            source.go.set()  # with the cut done first, the voice arrives after its blank

        interrupter = threading.Thread(target=interrupt)
        interrupter.start()
        interrupter.join(5.0)
        assert source.go.wait(5.0)
    finally:
        feeder.stop()
        feeder.join(5.0)
    queued = ring.read(ring.available())
    assert len(queued) >= int(0.1 * RATE)
    assert np.all(queued[:cut] == 0.5) and not queued[cut:].any()
    heard = line.take(line.end)
    assert np.all(heard[:cut] == 0.5) and not heard[cut:].any()
