"""The live session on its own, no framework: player mode on a virtual speaker, follower mode
with a fake speaker reporting what it played; the recorder as the backend."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from convodrive.audio.source import ANALYSIS_RATE
from convodrive.generators.base import Event
from convodrive.pipeline.session import LiveSession
from tests.conftest import wait_for
from tests.pipeline.session.helpers import CHUNK, CLOSED, feed_silence, mouth, onset, told_at, voice

pytestmark = [pytest.mark.espeak]


def open_session(tmp_path, mode: str, **kw) -> LiveSession:
    return LiveSession.open(
        mode=mode,
        backends=("record",),
        out_dir=tmp_path,
        generator_options={"phones": False},
        self_rate=ANALYSIS_RATE,
        **kw,
    )


def feed_fast(session: LiveSession, pcm: np.ndarray, segment, chunk: float = 0.02) -> None:
    """A speech synthesiser faster than real time: everything at once, in chunks."""
    n = int(chunk * ANALYSIS_RATE)
    for i in range(0, len(pcm), n):
        session.feed_self(pcm[i : i + n].tobytes(), ANALYSIS_RATE, segment=segment)


def test_player_plays_the_voice_and_moves_the_mouth_with_it(tmp_path):
    pcm = voice()
    reports = []
    session = open_session(tmp_path, "player")
    session.on_playback(reports.append)
    stop = threading.Event()
    feed_silence(session, 10.0, stop)
    try:
        wait_for(lambda: session.time_at(time.monotonic()) is not None, "the session's clock")
        time.sleep(0.3)
        fed_at = time.monotonic()
        feed_fast(session, pcm, "reply-1")
        session.end_self("reply-1")
        wait_for(
            lambda: any(r.kind == "finished" for r in reports),
            "the finished report",
            timeout=len(pcm) / ANALYSIS_RATE + 5,
        )
    finally:
        stop.set()
        session.close()
    assert [r.kind for r in reports] == ["started", "finished"]
    assert not reports[1].interrupted
    assert reports[1].position == pytest.approx(len(pcm) / ANALYSIS_RATE, abs=0.05)
    kinds = [e.kind for _, e in session.events]
    assert kinds.index(Event.SPEAKING_START) < kinds.index(Event.SPEAKING_END)
    # The speaker played the voice: the played samples hold it, once, less what came after its
    # time (a feeder the CPU starved past its lead): the speaker played silence there and counted it.
    played = session.speaker.samples()
    assert np.abs(played).max() > 0.3
    voiced = np.count_nonzero(np.abs(played) > 0.02) / ANALYSIS_RATE
    expected = np.count_nonzero(np.abs(pcm / 32768.0) > 0.02) / ANALYSIS_RATE
    late = session.speaker.ring.underrun_samples / ANALYSIS_RATE
    assert expected * 0.95 - late <= voiced <= expected * 1.05
    # The mouth opens with the played voice, not with the feeding (lead ahead of it).
    first = np.nonzero(np.abs(played) > 0.05)[0][0] / ANALYSIS_RATE
    times, jaw = mouth(session)
    opened = onset(times, jaw, fed_at)
    assert opened is not None
    assert abs(opened - session.speaker.mono_of(first)) < 0.1
    assert session.fed_to_sent["record"].summary()["count"] > 0


def test_player_interruption_drops_unplayed_voice_and_shuts_the_mouth(tmp_path):
    pcm = voice()
    reports = []
    session = open_session(tmp_path, "player")
    session.on_playback(reports.append)
    stop = threading.Event()
    feed_silence(session, 10.0, stop)
    try:
        wait_for(lambda: session.time_at(time.monotonic()) is not None, "the session's clock")
        feed_fast(session, pcm, "reply-1")
        wait_for(lambda: any(r.kind == "started" for r in reports), "the started report")
        time.sleep(1.0)
        cut = time.monotonic()
        session.clear_self()
        feed_fast(session, pcm[:8000], "reply-1")  # late audio of the cut reply: dropped
        time.sleep(1.0)
    finally:
        stop.set()
        session.close()
    finished = [r for r in reports if r.kind == "finished"]
    assert len(finished) == 1 and finished[0].interrupted
    played = session.speaker.samples()
    told = told_at(session, Event.INTERRUPTED)
    after = int((session.speaker.position_at(told) + 0.03) * ANALYSIS_RATE)
    assert np.abs(played[after:]).max() < 1e-6  # nothing of the reply after the cut (one block)
    assert np.abs(played[:after]).max() > 0.3
    # The position told is how much of the reply played: the part of it the speaker played
    # before the cut, whatever silence a slow feed put in between.
    voiced = np.count_nonzero(np.abs(played[:after]) > 0.02) / ANALYSIS_RATE
    heard = pcm[: int(finished[0].position * ANALYSIS_RATE)] / 32768.0
    assert voiced == pytest.approx(np.count_nonzero(np.abs(heard) > 0.02) / ANALYSIS_RATE, abs=0.03)
    assert session.voice.dropped > 0.5
    times, jaw = mouth(session)
    assert jaw[(times > cut - 0.5) & (times < cut)].max() > 0.2  # talking up to the cut
    assert jaw[times > cut + 0.1].max() < CLOSED
    assert [e.kind for _, e in session.events][-1] is Event.INTERRUPTED


class FakeSpeaker(threading.Thread):
    """A framework's speaker: plays 40 ms chunks in real time and reports each after playing it
    (Pipecat's pushes from its output transport)."""

    def __init__(self, session: LiveSession, pcm: np.ndarray, segment, stop_at: float | None = None) -> None:
        super().__init__(daemon=True)
        self.session, self.pcm, self.segment, self.stop_at = session, pcm, segment, stop_at
        self.played: list[float] = []

    def run(self) -> None:
        n = int(CHUNK * ANALYSIS_RATE)
        t0 = time.monotonic()
        for k, i in enumerate(range(0, len(self.pcm), n)):
            time.sleep(max(t0 + (k + 1) * CHUNK - time.monotonic(), 0))
            start = time.monotonic() - CHUNK
            self.played.append(start)
            self.session.self_played(self.segment, i / ANALYSIS_RATE, at=start)
            if self.stop_at is not None and time.monotonic() >= self.stop_at:
                return


def test_follower_follows_the_reported_play_times_with_its_delay(tmp_path):
    pcm = voice()
    session = open_session(tmp_path, "follower")
    stop = threading.Event()
    feed_silence(session, 10.0, stop)
    try:
        wait_for(lambda: session.time_at(time.monotonic()) is not None, "the session's clock")
        time.sleep(0.3)
        feed_fast(session, pcm, "r")
        session.end_self("r")
        speaker = FakeSpeaker(session, pcm, "r")
        speaker.start()
        speaker.join()
        time.sleep(0.5)
    finally:
        stop.set()
        session.close()
    first_voice = np.nonzero(np.abs(pcm) > 0.05 * 32768)[0][0] / ANALYSIS_RATE
    heard = speaker.played[0] + first_voice
    times, jaw = mouth(session)
    opened = onset(times, jaw, speaker.played[0])
    assert opened is not None
    # The mouth opens `delay` after the voice, within a chunk and a frame.
    assert abs(opened - heard - session.delay) < CHUNK + 1 / 30 + 0.03
    starts = [e for _, e in session.events if e.kind is Event.SPEAKING_START]
    assert starts and abs(starts[0].at - (session.time_at(speaker.played[0]) + session.delay)) < 1e-3


def test_follower_ignores_a_chunk_reported_after_the_interruption(tmp_path):
    pcm = voice()
    session = open_session(tmp_path, "follower")
    stop = threading.Event()
    feed_silence(session, 10.0, stop)
    try:
        wait_for(lambda: session.time_at(time.monotonic()) is not None, "the session's clock")
        feed_fast(session, pcm, "r")
        speaker = FakeSpeaker(session, pcm, "r", stop_at=time.monotonic() + 1.2)
        speaker.start()
        speaker.join()
        cut = time.monotonic()
        session.clear_self(at=cut)
        session.self_played("r", 1.3, at=time.monotonic())  # the chunk in flight, reported late
        time.sleep(0.8)
    finally:
        stop.set()
        session.close()
    assert session.follower.ignored_reports == 1
    times, jaw = mouth(session)
    shown = cut + session.delay  # the motion runs `delay` behind the voice
    assert jaw[(times > shown - 0.6) & (times < shown - 0.1)].max() > 0.2
    assert jaw[times > shown + 0.1].max() < CLOSED


def test_events_reach_the_generator_on_the_time_line(tmp_path):
    session = open_session(tmp_path, "player")
    stop = threading.Event()
    feed_silence(session, 5.0, stop)
    try:
        wait_for(lambda: session.time_at(time.monotonic()) is not None, "the session's clock")
        now = time.monotonic()
        session.event(Event.USER_TURN_END, at=now)
        session.event(Event.TOOL_START, at=now + 0.2, name="lookup")
        time.sleep(1.5)
    finally:
        stop.set()
        session.close()
    sent = [e for _, e in session.events]
    assert [e.kind for e in sent] == [Event.USER_TURN_END, Event.TOOL_START]
    assert sent[1].info == {"name": "lookup"}
    assert sent[0].at == pytest.approx(session.time_at(now) + session.partner_delay, abs=0.02)
    assert session.generator.conversation.state_at(sent[1].at + 0.1).planning
    times, jaw = mouth(session)
    assert jaw.max() < CLOSED
    assert session.result is not None and session.result.report_path.exists()
