"""The monitor's capture times (``Recording.mono_at``), worked out from its callbacks' timings as an
audio server reports them: smoothed through the server's small latency revisions, split where a
stall moved the time line."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from convodrive.audio.live.capture import Recording
from convodrive.audio.source import ANALYSIS_RATE

RATE = ANALYSIS_RATE


class _Device:
    """What a ``Recording`` reads of its capture device: the rate, and each callback's (ring
    position, monotonic time of ring position 0)."""

    def __init__(self, anchor_at: Callable[[float], float]) -> None:
        self.rate = RATE
        firsts = range(0, 12 * RATE, 160)  # 10 ms callbacks over 12 s
        late = np.random.default_rng(0).uniform(0.0, 0.004, len(firsts))  # callbacks come a little late
        self.timing = [(first, anchor_at(first / RATE) + delay) for first, delay in zip(firsts, late)]


def _times(anchor_at: Callable[[float], float], seconds: list[float]) -> np.ndarray:
    recording = Recording(_Device(anchor_at))  # type: ignore[arg-type]
    return recording.mono_at(np.array(seconds) * RATE) - np.array(seconds)


def test_capture_times_ride_through_a_latency_revision() -> None:
    """A revision of 20 ms (a sink that starts playing) is smoothed over, not followed."""
    times = _times(lambda t: 100.0 if t < 3.0 else 100.02, [1.5, 2.5, 6.0, 9.0])
    assert np.all(np.abs(times - 100.01) <= 0.015), times


def test_a_stall_splits_the_time_line_and_each_side_keeps_its_own() -> None:
    """The server stalled 1.7 s at 4 s of audio: what came before is timed by the timings before
    it, what came after by those after (the median of the whole window timed every sample before
    the stall 1.7 s late)."""
    times = _times(lambda t: 100.0 if t < 4.0 else 101.7, [1.5, 2.0, 3.9, 4.1, 6.0, 11.0])
    np.testing.assert_allclose(times, [100.0, 100.0, 100.0, 101.7, 101.7, 101.7], atol=0.005)
