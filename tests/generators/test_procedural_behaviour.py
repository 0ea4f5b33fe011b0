"""The procedural generator's behaviour on espeak-ng dialogues: lip sync, a closed mouth while self
is silent, and more head motion while speaking than while listening (issue 3's figures)."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.source import DyadicAudio
from convodrive.eval.behaviour import behaviour_figures
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from tests.procedural_dialogues import make, reference, with_bleed

NAMES = ("alternating", "self_monologue", "partner_monologue", "overlap", "story")

pytestmark = [pytest.mark.espeak]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("dialogues")
    return {name: make(name, d) for name in NAMES}


@pytest.fixture(scope="module")
def dialogues(made):
    return {name: audio for name, (_, audio) in made.items()}


@pytest.fixture(scope="module")
def figures(dialogues):
    gen = ProceduralGenerator()
    return {name: behaviour_figures(gen.generate(audio, seed=11)[0], audio) for name, audio in dialogues.items()}


@pytest.mark.parametrize("name", ["alternating", "self_monologue", "overlap"])
def test_jaw_follows_self_speech_envelope(figures, name):
    assert figures[name]["lip_sync"]["pearson_jaw_vs_self_envelope"] >= 0.6


@pytest.mark.parametrize("name", ["alternating", "self_monologue", "partner_monologue", "overlap"])
def test_mouth_closed_while_self_silent(figures, name):
    lip = figures[name]["lip_sync"]
    assert lip["jaw_closed_when_self_silent"] >= 0.95
    for key in ("jaw_closed_when_only_partner_speaks", "jaw_closed_when_both_silent"):
        if lip[key] is not None:
            assert lip[key] >= 0.95, key


def test_partner_monologue_leaves_the_mouth_shut_and_the_head_calm(figures):
    f = figures["partner_monologue"]
    assert f["activity"]["only_partner_frames"] > 150
    assert f["lip_sync"]["jaw_closed_when_only_partner_speaks"] == 1.0
    assert f["head"]["mean_angular_speed_only_partner_deg_s"] < 6.0


@pytest.mark.parametrize("name", ["alternating", "overlap"])
def test_head_moves_more_while_speaking_than_listening(figures, name):
    head = figures[name]["head"]
    assert head["speaking_to_listening_ratio"] >= 2.0


def test_spectral_fallback_alone_keeps_lip_sync(dialogues):
    audio = dialogues["alternating"]
    clip = ProceduralGenerator({"phones": False}).generate(audio, seed=2)[0]
    assert clip.metadata["phones"] is False
    lip = behaviour_figures(clip, audio)["lip_sync"]
    assert lip["pearson_jaw_vs_self_envelope"] >= 0.6
    assert lip["jaw_closed_when_self_silent"] >= 0.95


def test_gestures_and_blinks_happen_while_speaking(dialogues):
    audio = dialogues["self_monologue"]
    f = behaviour_figures(ProceduralGenerator().generate(audio, seed=4)[0], audio)
    assert f["arms"]["mean_speed_self_speaking_deg_s"] > 5.0
    assert f["blinks_per_minute"]["self_speaking"] > 0
    assert f["gaze"]["mean_eye_angle_self_speaking_deg"] > 1.0


@pytest.mark.parametrize("gain, noise_db", [(1.0, -42.0), (0.08, -75.0)])
def test_noisy_and_quiet_recordings_keep_the_figures(dialogues, gain, noise_db):
    """The voice tracker adapts to the noise floor and to the speaker's level."""
    clean = dialogues["alternating"]
    rng = np.random.default_rng(1)
    sigma = 10 ** (noise_db / 20)
    audio = DyadicAudio(
        *(
            np.clip(v * gain + rng.normal(0, sigma, len(v)), -1, 1).astype(np.float32)
            for v in (clean.self_voice, clean.other_voice)
        )
    )
    f = behaviour_figures(ProceduralGenerator().generate(audio, seed=11)[0], audio)
    assert f["activity"]["self_speaking_frames"] > 150 and f["activity"]["only_partner_frames"] > 100
    assert f["lip_sync"]["pearson_jaw_vs_self_envelope"] >= 0.6
    assert f["lip_sync"]["jaw_closed_when_self_silent"] >= 0.95
    assert f["lip_sync"]["mean_jaw_open_self_speaking"] > 0.15
    assert f["head"]["speaking_to_listening_ratio"] >= 2.0


def test_gaze_averts_when_taking_the_turn_and_returns_while_listening(dialogues):
    from convodrive.motion.skeleton import JOINT_INDEX as J

    clip = ProceduralGenerator().generate(dialogues["alternating"], seed=11)[0]
    eye = np.degrees(np.linalg.norm(clip.pose[:, J["left_eye_smplhf"]], axis=1))
    speaking = clip.vad[:, 0] > 0
    onsets = [k for k in range(15, len(speaking)) if speaking[k] and not speaking[k - 15 : k].any()]
    assert len(onsets) >= 2
    for k in onsets:
        assert eye[k + 3 : k + 15].max() > 6.0  # looks away as the turn starts
    listening = (clip.vad[:, 1] > 0) & ~speaking
    assert np.median(eye[listening]) < 3.0  # and at the partner while listening


def test_blinks_more_while_speaking_than_listening_and_at_turn_starts(dialogues):
    """Averaged over 12 takes (one analysis), so the comparison of rates is not luck of one seed."""
    audio = dialogues["alternating"]
    clips = ProceduralGenerator({"phones": False}).generate(audio, seed=5, num_samples=12)
    rates = [behaviour_figures(c, audio)["blinks_per_minute"] for c in clips]
    speaking = float(np.mean([r["self_speaking"] for r in rates]))
    listening = float(np.mean([r["only_partner"] for r in rates]))
    assert 15.0 <= speaking <= 35.0
    assert listening <= 16.0
    assert speaking >= 2.0 * listening
    # Most turns self takes start with a blink within the first 300 ms.
    starts = hits = 0
    for clip in clips:
        speaking_mask = clip.vad[:, 0] > 0
        lids = clip.face[:, B["eyeBlinkLeft"]]
        for k in range(15, len(speaking_mask) - 10):
            if speaking_mask[k] and not speaking_mask[k - 15 : k].any():
                starts += 1
                hits += bool(lids[k : k + 10].max() > 0.5)
    assert starts >= 24 and hits >= 0.6 * starts


@pytest.mark.parametrize("name", ["alternating", "partner_monologue", "overlap", "story"])
def test_partner_bleeding_into_self_at_minus_12_db_leaves_the_mouth_shut(made, name):
    """Graded against the dialogue's own turns, not a level detector that the bleed fools too."""
    path, audio = made[name]
    bled = with_bleed(audio, -12.0)
    f = behaviour_figures(ProceduralGenerator().generate(bled, seed=3)[0], bled, reference(path))
    assert f["voice_activity"]["self_on_when_only_partner_speaks"] <= 0.05
    assert f["lip_sync"]["jaw_closed_when_only_partner_speaks"] >= 0.95
    if name != "partner_monologue":
        assert f["voice_activity"]["self_on_when_self_speaks"] >= 0.9
        assert f["lip_sync"]["pearson_jaw_vs_self_envelope"] >= 0.6
