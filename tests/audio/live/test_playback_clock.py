"""The playback clock against a real audio server: time is where the played stream is."""

from __future__ import annotations

import time

import numpy as np
import pytest

from convodrive.audio.live.capture import MicrophoneInput, Recording
from convodrive.audio.live.devices import find_device
from convodrive.audio.live.playback import Playback
from convodrive.scheduler import PlaybackClock
from tests.conftest import realtime_allowed
from tests.pulse import MONITOR, SPEAKER

pytestmark = [pytest.mark.pulseaudio, pytest.mark.live]


def test_clock_reads_where_the_speaker_is(pulse, monkeypatch) -> None:
    for key, value in pulse.env.items():
        monkeypatch.setenv(key, value)
    rate = 16000
    playback = Playback(find_device(SPEAKER, "output", "--play"), rate, ring_seconds=4.0, latency=0.15)
    monitor = Recording(MicrophoneInput(find_device(MONITOR, "input", "--monitor"), ring_seconds=2.0))
    clicks = np.arange(1.0, 3.6, 0.37)  # stream seconds
    signal = np.zeros(int(4.0 * rate), np.float32)
    for t in clicks:
        i = int(t * rate)
        signal[i : i + 80] = 0.8 * np.sin(np.arange(80) * 2 * np.pi * 1000 / rate)
    assert playback.ring.write(signal) == len(signal)
    clock = PlaybackClock(playback)
    monitor.source.start()
    monitor.start()
    clock.start(0.0)
    readings = []  # (monotonic time, what the clock said then), as the scheduler reads it
    woke = []
    try:
        for t in clicks:
            while clock.now() < t - 0.05:
                readings.append((time.monotonic(), clock.now()))
                time.sleep(0.01)
            clock.wait_until(t)
            woke.append((time.monotonic(), clock.now()))
        clock.wait_until(clicks[-1] + 0.3)
    finally:
        clock.close()
        monitor.stop()
    recording = monitor.samples()
    loud = np.flatnonzero(np.abs(recording) > 0.3)
    starts = loud[np.concatenate([[True], np.diff(loud) > rate // 10])]
    heard = monitor.mono_at(starts)
    assert len(heard) == len(clicks), (len(heard), len(clicks))
    # Where did the clock, as read shortly before each click, say the click would be heard?
    readings_arr = np.asarray(readings)
    predicted = []
    for t in clicks:
        mono, now = readings_arr[readings_arr[:, 1] <= t - 0.05][-1]
        predicted.append(mono + (t - now))
    error_ms = 1000.0 * (np.asarray(predicted) - heard)
    # 150 ms of output latency: a clock that ignored where the speaker is would be off by that much.
    assert playback.latency >= 0.1
    assert np.all(np.abs(error_ms) < 10.0), error_ms
    # Waiting never returns early (a busy CPU may only make it late).
    assert all(now >= t for (_, now), t in zip(woke, clicks))
    if realtime_allowed():  # the clock's source and the capture wait behind no ordinary process
        assert playback.report()["callback_priority"].startswith("SCHED_FIFO")
        assert monitor.source.report()["callback_priority"].startswith("SCHED_FIFO")
