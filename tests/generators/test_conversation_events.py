"""Conversation events (``generators.events``) and what the procedural generator shows of them:
the look-away while planning, the mouth shut on interruption, relaxing when idle."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.source import ANALYSIS_RATE, DyadicAudio
from convodrive.generators.base import ConversationEvent, Event
from convodrive.generators.events import EventLog
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.skeleton import JOINT_INDEX as J

CLOSED = 0.05
"""jawOpen below this is a closed mouth (the in-breath parts the lips to 0.035)."""


def test_state_follows_events_in_time_order_whatever_order_they_arrive():
    log = EventLog()
    log.add(ConversationEvent(Event.SPEAKING_START, 2.0))
    log.add(ConversationEvent(Event.USER_TURN_END, 1.0))  # arrives late, applies at its time
    assert log.state_at(0.5).thinking_since is None
    assert log.state_at(1.5).planning and log.state_at(1.5).mouth_shut
    speaking = log.state_at(2.5)
    assert speaking.speaking_since == 2.0 and not speaking.planning and not speaking.mouth_shut
    log.add(ConversationEvent(Event.INTERRUPTED, 3.0))
    assert log.state_at(3.1).mouth_shut and log.state_at(3.1).speaking_since is None
    log.add(ConversationEvent(Event.IDLE, 4.0))
    assert log.state_at(9.0).idle_for(9.0) == pytest.approx(5.0)
    assert log.state_at(9.0).interrupted_since is None  # idle is a fresh start
    assert [s.thinking_since for s in log.states([0.0, 1.0, 2.0])] == [None, 1.0, None]


def test_old_events_fold_into_the_base_state():
    log = EventLog(keep=4)
    log.add(ConversationEvent(Event.TOOL_START, 0.5))
    for i in range(10):
        log.add(ConversationEvent(Event.USER_SPEECH_START if i % 2 else Event.USER_SPEECH_STOP, 1.0 + i))
    assert len(log) == 4
    assert log.state_at(20.0).tool_since == 0.5


@pytest.fixture(scope="module")
def voice():
    from convodrive.audio.synth import speak

    text = "Well, I think the best way to get there is to take the train and then walk along the river."
    return speak(text)


def dyadic(self_voice: np.ndarray, seconds: float, at: float = 0.5) -> DyadicAudio:
    n = int(seconds * ANALYSIS_RATE)
    own = np.zeros(n, np.float32)
    start = int(at * ANALYSIS_RATE)
    own[start : start + len(self_voice)] = self_voice[: n - start]
    return DyadicAudio(self_voice=own, other_voice=np.zeros(n, np.float32))


def stream(gen: ProceduralGenerator, audio: DyadicAudio, post: dict[float, ConversationEvent] | None = None):
    """Frames streamed chunk by chunk; each event in ``post`` is sent when the audio has reached
    its key (seconds), as a live session would send it."""
    post = dict(post or {})

    def chunks():
        for chunk in audio.chunks(ANALYSIS_RATE // 50):
            for when in [w for w in post if w <= chunk.time]:
                gen.on_event(post.pop(when))
            yield chunk

    frames = list(gen.stream(chunks(), seed=1))
    return np.array([f.face[B["jawOpen"]] for f in frames]), np.stack([f.pose for f in frames])


@pytest.mark.espeak
def test_interruption_shuts_the_mouth_within_100_ms(voice):
    audio = dyadic(voice, 4.0)
    jaw_free, _ = stream(ProceduralGenerator({"phones": False}), audio)
    cut = 1.5
    gen = ProceduralGenerator({"phones": False})
    # Sent when the audio is already 100 ms past the cut: frames before it are made.
    jaw, pose = stream(gen, audio, {cut + 0.1: ConversationEvent(Event.INTERRUPTED, cut)})
    after = slice(int((cut + 0.1) * 30) + 1, int(3.5 * 30))
    assert jaw_free[after].max() > 0.3  # the voice goes on: without the event the mouth would move
    assert jaw[after].max() < CLOSED
    assert np.abs(pose[after, J["jaw"]]).max() < np.abs(pose[:, J["jaw"]]).max() * 0.2
    before = slice(int(0.6 * 30), int(cut * 30))
    assert np.allclose(jaw[before], jaw_free[before])  # nothing changes before the event


@pytest.mark.espeak
def test_speaking_again_after_an_interruption_opens_the_mouth(voice):
    audio = dyadic(voice, 4.0)
    gen = ProceduralGenerator({"phones": False})
    gen.on_event(ConversationEvent(Event.INTERRUPTED, 1.0))
    gen.on_event(ConversationEvent(Event.SPEAKING_START, 2.0))
    jaw, _ = stream(gen, audio)
    assert jaw[int(1.15 * 30) : int(2.0 * 30)].max() < CLOSED
    assert jaw[int(2.1 * 30) : int(3.5 * 30)].max() > 0.3


def eye_angle(pose: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(pose[:, J["left_eye_smplhf"]], axis=1))


@pytest.mark.espeak
def test_thinking_looks_away_tilts_the_head_and_keeps_the_mouth_shut(voice):
    audio = dyadic(voice, 4.0, at=2.5)  # the reply's voice starts at 2.5 s
    _, calm = stream(ProceduralGenerator({"phones": False}), audio)
    gen = ProceduralGenerator({"phones": False})
    gen.on_event(ConversationEvent(Event.USER_TURN_END, 0.5))
    gen.on_event(ConversationEvent(Event.TOOL_START, 1.0))
    gen.on_event(ConversationEvent(Event.TOOL_END, 1.8))
    gen.on_event(ConversationEvent(Event.SPEAKING_START, 2.5))
    jaw, pose = stream(gen, audio)
    think = slice(int(0.9 * 30), int(2.4 * 30))
    assert eye_angle(pose[think]).mean() > eye_angle(calm[think]).mean() + 8.0
    roll = lambda p: np.degrees(p[:, J["head"], 2])  # noqa: E731
    assert np.abs(roll(pose[think]) - roll(calm[think])).mean() > 1.0
    assert jaw[think].max() < CLOSED
    back = slice(int(3.2 * 30), int(3.9 * 30))  # speaking: eyes return to the partner
    assert eye_angle(pose[back]).mean() < eye_angle(pose[think]).mean() - 8.0


def test_long_idle_relaxes_into_breathing_and_slow_glances():
    audio = DyadicAudio(
        self_voice=np.zeros(16 * ANALYSIS_RATE, np.float32),
        other_voice=np.zeros(16 * ANALYSIS_RATE, np.float32),
    )
    _, calm = stream(ProceduralGenerator({"phones": False}), audio)
    gen = ProceduralGenerator({"phones": False})
    gen.on_event(ConversationEvent(Event.IDLE, 0.0))
    _, idle = stream(gen, audio)
    late = slice(8 * 30, 16 * 30)
    spine = lambda p: np.degrees(p[late, J["spine3"], 0])  # noqa: E731
    assert spine(idle).std() > 2.0 * spine(calm).std()
    assert np.ptp(eye_angle(idle[late])) > np.ptp(eye_angle(calm[late])) + 3.0
    early = slice(0, 4 * 30)  # not yet: idle for under IDLE_RELAX seconds changes nothing much
    assert np.abs(eye_angle(idle[early]) - eye_angle(calm[early])).max() < 1.0


def test_without_events_streaming_is_untouched():
    rng = np.random.default_rng(0)
    noise = (0.1 * rng.standard_normal(3 * ANALYSIS_RATE)).astype(np.float32)
    audio = DyadicAudio(self_voice=noise, other_voice=np.zeros_like(noise))
    gen = ProceduralGenerator({"phones": False})
    clip = gen.generate(audio, seed=1)[0]
    _, pose = stream(gen, audio)
    assert np.array_equal(clip.pose, pose)
