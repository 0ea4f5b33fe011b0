"""What the player tells a framework about each segment it plays: its own audio counts, not the
silence the feeder put between its parts; times are when the speaker played the samples."""

from __future__ import annotations

import numpy as np

from convodrive.audio.live.ring import SampleRing
from convodrive.pipeline.session.inputs import QueuedVoice
from convodrive.pipeline.session.playing import PlaybackTracker

RATE = 16000


def queue(voice: QueuedVoice, ring: SampleRing, samples: int) -> None:
    """What the feeder does with the voice: read it into the ring."""
    ring.write(voice.read(samples, 0.0))


def setup() -> tuple[SampleRing, QueuedVoice, PlaybackTracker, list]:
    ring, tracker, reports = SampleRing(4 * RATE), PlaybackTracker(), []
    voice = QueuedVoice(RATE, ring, ahead=3.0, on_start=tracker.queued)
    tracker.listeners.append(reports.append)
    ring.write(np.zeros(RATE // 10, np.float32))  # silence before the reply
    return ring, voice, tracker, reports


def test_a_reply_that_came_slower_than_it_plays_reports_its_own_length() -> None:
    ring, voice, tracker, reports = setup()
    voice.feed("r", np.ones(RATE // 2, np.float32), RATE)
    queue(voice, ring, RATE)
    ring.write(np.zeros(RATE // 4, np.float32))  # the feeder padded: the rest came late
    voice.feed("r", np.ones(RATE // 2, np.float32), RATE)
    voice.end("r")
    tracker.ended("r")
    queue(voice, ring, RATE)
    queue(voice, ring, RATE)  # the end
    at_of = lambda pos: 100.0 + pos / RATE  # noqa: E731 (ring position 0 played at 100 s)
    done = tracker.poll(voice, ring.write_pos, RATE, at_of)
    assert [(r.kind, r.interrupted) for r in reports] == [("started", False), ("finished", False)]
    assert reports[0].at == at_of(RATE // 10)
    assert reports[1].position == 1.0  # one second of voice, played over 1.25 s
    assert done == [("r", ring.write_pos)] and reports[1].at == at_of(ring.write_pos)


def test_an_interrupted_reply_reports_what_played_of_it_before_the_cut() -> None:
    ring, voice, tracker, reports = setup()
    voice.feed("r", np.ones(RATE // 2, np.float32), RATE)
    queue(voice, ring, RATE)
    ring.write(np.zeros(RATE // 4, np.float32))
    voice.feed("r", np.ones(RATE // 2, np.float32), RATE)
    queue(voice, ring, RATE)
    cut = RATE // 10 + RATE // 2 + RATE // 4 + RATE // 10  # 100 ms into the second part
    tracker.cleared(voice, cut, RATE, at=7.0)
    assert len(reports) == 1 and reports[0].interrupted and reports[0].at == 7.0
    assert reports[0].position == 0.6
