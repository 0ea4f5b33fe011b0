"""The sample ring between an audio callback and a thread: counts, never blocks, keeps time."""

from __future__ import annotations

import numpy as np

from convodrive.audio.live.ring import SampleRing


def test_underrun_plays_silence_and_keeps_the_time_line() -> None:
    ring = SampleRing(100)
    assert ring.write(np.arange(30, dtype=np.float32)) == 30
    out = np.full(50, -1.0, np.float32)
    assert ring.read_into(out) == 20  # 20 samples were missing
    np.testing.assert_array_equal(out[:30], np.arange(30))
    assert not out[30:].any() and ring.underruns == 1 and ring.underrun_samples == 20
    assert ring.read_pos == 50, "the speaker's position advanced by what it played, silence included"
    # Samples that arrive for positions already played are skipped, so later ones stay on time.
    assert ring.write(np.full(25, 7.0, np.float32)) == 25
    assert ring.write_pos == 55 and ring.available() == 5
    out = np.zeros(5, np.float32)
    assert ring.read_into(out) == 0 and np.all(out == 7.0)


def test_overrun_drops_new_samples_and_counts_them() -> None:
    ring = SampleRing(64)
    ring.write_or_drop(np.ones(50, np.float32))
    ring.write_or_drop(np.full(30, 2.0, np.float32))
    assert ring.overruns == 1 and ring.overrun_samples == 16
    got = ring.read(100)
    assert len(got) == 64 and np.all(got[:50] == 1.0) and np.all(got[50:] == 2.0)


def test_wraps_around() -> None:
    ring = SampleRing(10)
    data = np.arange(1000, dtype=np.float32)
    out = []
    for i in range(0, 1000, 7):
        ring.write(data[i : i + 7])
        out.append(ring.read(7))
    np.testing.assert_array_equal(np.concatenate(out), data)


def test_blank_silences_what_is_queued_from_a_position_on() -> None:
    """An interruption: what the reader has not reached from ``start`` on becomes silence, across
    the wrap; what was read, and what is written afterwards, is untouched."""
    ring = SampleRing(10)
    ring.write(np.arange(1, 9, dtype=np.float32))
    ring.read(6)
    ring.write(np.full(6, 9.0, np.float32))  # positions 8..13 wrap around the buffer
    ring.blank(3)  # before the read position: blanks from the read position (6) on
    assert np.all(ring.read(8) == 0.0)
    ring.write(np.arange(1, 5, dtype=np.float32))
    ring.blank(16)
    np.testing.assert_array_equal(ring.read(4), [1, 2, 0, 0])


def test_timeline_blank_silences_what_is_not_yet_taken() -> None:
    from convodrive.audio.live.timeline import Timeline

    line = Timeline()
    line.append(np.ones(5, np.float32))
    line.append(np.full(5, 2.0, np.float32))
    np.testing.assert_array_equal(line.take(3), [1, 1, 1])
    line.blank(4)
    np.testing.assert_array_equal(line.take(10), [1, 0, 0, 0, 0, 0, 0])


def test_timeline_blank_to_a_stop_also_silences_what_comes_later() -> None:
    """A cut silences up to where the voice was queued, also samples of that stretch still on their
    way (in a resampler): they come in silent; what follows the stretch comes in whole."""
    from convodrive.audio.live.timeline import Timeline

    line = Timeline()
    line.append(np.ones(4, np.float32))
    line.blank(2, 7)
    line.append(np.full(2, 2.0, np.float32))
    line.append(np.full(3, 3.0, np.float32))
    np.testing.assert_array_equal(line.take(9), [1, 1, 0, 0, 0, 0, 0, 3, 3])
