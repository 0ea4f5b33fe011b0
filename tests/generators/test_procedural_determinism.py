"""Seeds, takes, options, streaming equal to offline, and the declared look-ahead honoured."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.source import DyadicAudio
from convodrive.generators.base import take_seed
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.plugins import load_plugin
from convodrive.plumbing.errors import UserError
from tests.procedural_dialogues import make

pytestmark = [pytest.mark.espeak]


@pytest.fixture(scope="module")
def audio(tmp_path_factory):
    return make("overlap", tmp_path_factory.mktemp("det"))[1]


@pytest.fixture(scope="module")
def gen():
    return ProceduralGenerator()


def test_registered_as_plugin():
    cls = load_plugin("convodrive.generators", "procedural")
    assert cls is ProceduralGenerator
    assert cls.name == "procedural" and cls.description
    # The analysis' 100 ms, plus the anticipation that sees pauses and turn starts coming.
    assert ProceduralGenerator().lookahead_frames == 3 + 9
    assert ProceduralGenerator({"anticipation": 0}).lookahead_frames == 3
    # Exactly: the features' 1846 samples past a frame's start (115 ms, of the 133 whole frames allow).
    assert ProceduralGenerator({"anticipation": 0}).lookahead_seconds == pytest.approx(1846 / 16000)
    assert ProceduralGenerator().lookahead_seconds == pytest.approx((1846 + 4800) / 16000)


def test_same_seed_reproduces_and_seeds_differ(gen, audio):
    a = gen.generate(audio, seed=7)[0]
    b = ProceduralGenerator().generate(audio, seed=7)[0]
    c = gen.generate(audio, seed=8)[0]
    assert np.array_equal(a.pose, b.pose) and np.array_equal(a.face, b.face)
    assert np.linalg.norm(a.pose - c.pose, axis=(1, 2)).mean() > 0
    assert a.num_frames == audio.num_frames


def test_samples_are_takes_with_their_own_seeds(gen, audio):
    takes = gen.generate(audio, seed=3, num_samples=3)
    assert [t.metadata["seed"] for t in takes] == [take_seed(3, i) for i in range(3)]
    assert np.array_equal(takes[1].pose, gen.generate(audio, seed=take_seed(3, 1))[0].pose)
    assert np.linalg.norm(takes[0].pose - takes[2].pose, axis=(1, 2)).mean() > 0
    # The voices are the same in every take: mouth and activity do not depend on the seed.
    assert np.array_equal(takes[0].vad, takes[2].vad)


@pytest.mark.parametrize("chunk", [160, 1600, 2999])
@pytest.mark.parametrize("anticipation", [0.3, 0.0, 0.1])
def test_streaming_in_chunks_equals_offline(audio, chunk, anticipation):
    gen = ProceduralGenerator({"anticipation": anticipation})
    offline = gen.generate(audio, seed=5)[0]
    frames = list(gen.stream(audio.chunks(chunk), seed=5))
    assert len(frames) == offline.num_frames
    assert [round(f.time * 30) for f in frames[:4]] == [0, 1, 2, 3]
    assert np.array_equal(np.stack([f.pose for f in frames]), offline.pose)
    assert np.array_equal(np.stack([f.face for f in frames]), offline.face)
    assert np.array_equal(np.stack([f.vad for f in frames]), offline.vad)


@pytest.mark.parametrize("k", [86, 94, 129])
@pytest.mark.parametrize("anticipation", [0.3, 0.0])
def test_frame_k_ignores_audio_after_its_lookahead(audio, k, anticipation):
    """Replace everything after frame k's start + lookahead_seconds with other sound: frames <= k
    stay. That exact figure (115 ms, within the declared whole frames) is a live partner's latency."""
    gen = ProceduralGenerator({"anticipation": anticipation})
    assert gen.lookahead_seconds <= (gen.lookahead_frames + 1) / 30
    cut = int(np.ceil(k * 16000 / 30 + gen.lookahead_seconds * 16000))
    rng = np.random.default_rng(0)
    changed = DyadicAudio(audio.self_voice.copy(), audio.other_voice.copy())
    changed.self_voice[cut:] = rng.normal(0, 0.2, len(audio.self_voice) - cut).astype(np.float32)
    changed.other_voice[cut:] = audio.self_voice[cut:][::-1]
    a = gen.generate(audio, seed=1)[0]
    b = gen.generate(changed, seed=1)[0]
    assert np.array_equal(a.pose[: k + 1], b.pose[: k + 1])
    assert np.array_equal(a.face[: k + 1], b.face[: k + 1])
    later = slice(k + 1, k + gen.lookahead_frames + 12)
    assert not np.array_equal(a.face[later], b.face[later])  # the change is visible later


def test_expressiveness_scales_motion(audio):
    def head_motion(e: float) -> float:
        clip = ProceduralGenerator({"expressiveness": e, "phones": False}).generate(audio, seed=1)[0]
        return float(np.abs(np.diff(clip.pose[:, 15], axis=0)).mean())

    assert head_motion(2.0) > 1.5 * head_motion(0.5)


def test_variability_zero_still_runs_and_seeds_still_differ(audio):
    gen = ProceduralGenerator({"variability": 0, "phones": False})
    a, b = gen.generate(audio, seed=1)[0], gen.generate(audio, seed=2)[0]
    assert np.isfinite(a.pose).all()
    assert np.linalg.norm(a.pose - b.pose, axis=(1, 2)).mean() > 0


@pytest.mark.parametrize(
    "options, word",
    [
        ({"expresiveness": 1}, "unknown option"),
        ({"expressiveness": "lots"}, "must be a number"),
        ({"variability": 9}, "between 0 and 3"),
        ({"phones": "yes"}, "true or false"),
    ],
)
def test_bad_options_are_user_errors(options, word):
    with pytest.raises(UserError, match=word):
        ProceduralGenerator(options)


def test_very_short_audio(gen):
    tiny = DyadicAudio(np.zeros(100, np.float32), np.zeros(100, np.float32))
    clips = gen.generate(tiny, seed=0)
    assert clips[0].num_frames == 1
    assert len(list(gen.stream(tiny.chunks(), seed=0))) == 1
