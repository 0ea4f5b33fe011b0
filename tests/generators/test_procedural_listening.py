"""The procedural generator as a listener (issue 10): measured with the behaviour eval against
each dialogue's own turns, over several takes, on the bundled dialogue and on espeak-ng
dialogues with long, short and laughing partner turns. Rates are pooled over the takes: one take
of a few seconds of listening holds too few blinks or nods for a rate."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.source import AudioSource
from convodrive.eval.behaviour import behaviour_figures, head_pitch
from convodrive.eval.segments import load_segments
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.generators.procedural.options import ProceduralOptions
from convodrive.generators.procedural.poses import LIBRARY
from convodrive.generators.procedural.posture import PostureSynth
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.rotations import axis_angle_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX as J
from convodrive.motion.skeleton import global_rotation
from tests.conftest import REPO
from tests.procedural_dialogues import make, reference

pytestmark = [pytest.mark.espeak]

TAKES = 6
LISTENING = ("bundled", "alternating", "partner_monologue", "story", "laughter")
"""Dialogues with at least 6 s of listening in each take."""


@pytest.fixture(scope="module")
def dialogues(tmp_path_factory):
    d = tmp_path_factory.mktemp("listening")
    out = {
        "bundled": (
            AudioSource(REPO / "samples/dialogue.wav").read_all(),
            load_segments(REPO / "samples/dialogue.json"),
        )
    }
    for name in ("alternating", "self_monologue", "partner_monologue", "overlap", "story", "laughter"):
        path, audio = make(name, d)
        out[name] = (audio, reference(path))
    return out


@pytest.fixture(scope="module")
def takes(dialogues):
    gen = ProceduralGenerator()
    out = {}
    for name, (audio, ref) in dialogues.items():
        clips = gen.generate(audio, seed=21, num_samples=TAKES)
        out[name] = (clips, [behaviour_figures(c, audio, ref) for c in clips])
    return out


def pooled_rate(figures: list[dict], section: str, key: str) -> float:
    """Events per minute over every take's listening frames together."""
    minutes = [f["activity"]["listening_frames"] / 30 / 60 for f in figures]
    return sum(f[section][key] * m for f, m in zip(figures, minutes)) / sum(minutes)


@pytest.mark.parametrize("name", LISTENING)
def test_the_listener_blinks_nods_on_pauses_and_moves(takes, name):
    _, figures = takes[name]
    assert 10.0 <= pooled_rate(figures, "blinks_per_minute", "listening") <= 20.0
    nods = sum(f["nods"]["listening_nods"] for f in figures)
    timed = sum(
        (f["nods"]["listening_share_within_600ms_after_partner_pause"] or 0) * f["nods"]["listening_nods"]
        for f in figures
    )
    assert pooled_rate(figures, "nods", "per_minute_listening") >= 4.0
    assert timed >= 0.5 * nods
    speeds = [f["head"]["mean_angular_speed_listening_deg_s"] for f in figures]
    assert min(speeds) >= 3.0
    ratios = [f["head"]["speaking_to_listening_ratio"] for f in figures if f["head"]["speaking_to_listening_ratio"]]
    if ratios:
        assert 2.0 <= float(np.mean(ratios)) <= 5.0


@pytest.mark.parametrize("name", ["bundled", "alternating", "self_monologue", "overlap", "story", "laughter"])
def test_lips_follow_self_and_rest_shut_otherwise(takes, name):
    for f in takes[name][1]:
        assert f["lip_sync"]["pearson_jaw_vs_self_envelope"] >= 0.8
        assert f["lip_sync"]["jaw_closed_when_self_silent"] >= 0.97


def test_speaking_blinks_stay_above_listening_blinks(takes):
    figures = [f for name in LISTENING for f in takes[name][1]]
    speaking_minutes = sum(f["activity"]["self_speaking_frames"] for f in figures) / 30 / 60
    speaking = sum(
        f["blinks_per_minute"]["self_speaking"] * f["activity"]["self_speaking_frames"] / 1800
        for f in figures
        if f["blinks_per_minute"]["self_speaking"] is not None
    )
    assert 18.0 <= speaking / speaking_minutes <= 35.0
    assert speaking / speaking_minutes > pooled_rate(figures, "blinks_per_minute", "listening") + 4.0


def test_listeners_look_at_the_partner_more_than_speakers_do_but_not_always(takes):
    figures = [f for name in LISTENING for f in takes[name][1]]
    listening = np.mean([f["gaze"]["at_partner_share_listening"] for f in figures])
    speaking = np.mean(
        [
            f["gaze"]["at_partner_share_self_speaking"]
            for f in figures
            if f["gaze"]["at_partner_share_self_speaking"] is not None
        ]
    )
    assert 0.8 <= listening < 0.99
    assert speaking < listening - 0.15


def test_smiles_answer_the_partners_laughter(dialogues, takes):
    audio, ref = dialogues["laughter"]
    laugh_start = ref.partner_speech[1][0]  # the partner's "ha ha ha" turn
    detected = int(laugh_start * 30) + 45  # the laughter detector needs five syllables
    answered = 0
    for clip in takes["laughter"][0]:
        smile = clip.face[:, [B["mouthSmileLeft"], B["mouthSmileRight"]]].mean(axis=1)
        answered += bool(smile[detected : detected + 45].max() >= 0.2)
        assert smile[: int(laugh_start * 30)].mean() < smile[detected : detected + 45].mean()
    assert answered >= TAKES - 1
    assert np.mean([f["smiles"]["share_listening"] for f in takes["laughter"][1]]) > 2 * np.mean(
        [f["smiles"]["share_listening"] for f in takes["partner_monologue"][1]]
    )


def _frames(ref, name: str) -> np.ndarray:
    return np.array([int(t * 30) for t in ref])


def test_takes_differ_while_listening_and_a_take_does_not_freeze(dialogues, takes):
    """The bundled dialogue's partner-only moments at 6.5, 13.5 and 20.5 s: the listening pose
    differs between takes and, within a take, from one moment to the next."""
    clips = takes["bundled"][0]
    moments = [int(t * 30) for t in (6.5, 13.5, 20.5)]
    _, ref = dialogues["bundled"]
    self_on, partner_on = ref.masks(clips[0].num_frames, 30)
    assert all(partner_on[k] and not self_on[k] for k in moments)

    def head_forward(clip, k):
        return global_rotation(axis_angle_to_matrix(clip.pose[k]), J["head"])[:, 2]

    def degrees_apart(a, b):
        return np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0)))

    def pose_rms(a, b):
        return float(np.degrees(np.sqrt(((a - b) ** 2).sum(axis=1).mean())))

    between = [
        degrees_apart(head_forward(a, k), head_forward(b, k))
        for k in moments
        for i, a in enumerate(clips)
        for b in clips[i + 1 :]
    ]
    assert np.mean(between) > 3.0
    assert (
        np.mean([pose_rms(a.pose[k], b.pose[k]) for k in moments for i, a in enumerate(clips) for b in clips[i + 1 :]])
        > 2.0
    )
    over_time = [pose_rms(c.pose[a], c.pose[b]) for c in clips for a, b in zip(moments, moments[1:])]
    assert min(over_time) > 1.0 and np.mean(over_time) > 2.0


def test_arms_rest_relaxed_and_differently_not_in_a_held_gesture(takes):
    """While listening the arms stay near the relaxed rest pose (no gesture is held), yet the rest
    differs between takes and changes within a take."""
    left = [J[f"left_{j}"] for j in ("shoulder", "elbow", "wrist")]
    rest = LIBRARY[0][:3]
    spreads = []
    for clip in takes["story"][0]:
        quiet = np.convolve(clip.vad[:, 0] > 0, np.ones(30), mode="full")[: clip.num_frames] == 0
        listening = np.flatnonzero((clip.vad[:, 1] > 0) & quiet)  # a second after self's last word
        arms = clip.pose[listening][:, left]
        assert np.degrees(np.linalg.norm(arms - rest, axis=2)).max() < 25.0
        spreads.append(np.degrees(np.linalg.norm(arms - arms.mean(axis=0), axis=2)).max())
    assert np.mean(spreads) > 3.0
    first = [clip.pose[200, left] for clip in takes["story"][0]]
    assert (
        np.mean([np.degrees(np.linalg.norm(a - b, axis=1)).max() for i, a in enumerate(first) for b in first[i + 1 :]])
        > 3.0
    )


def test_posture_shifts_every_10_to_30_seconds():
    """Four minutes of turns 8 s long: shifts come 10 to 30 s apart, or from 6 s at a turn change."""
    frames = 4 * 60 * 30
    t = np.arange(frames) // (8 * 30)
    vad_self = (t % 2 == 0).astype(float)
    for seed in range(4):
        synth = PostureSynth(ProceduralOptions(), seed)
        body = np.concatenate(
            [
                synth.step(k, vad_self[k : k + 100], 1 - vad_self[k : k + 100], np.zeros(100))["posture"]
                for k in range(0, frames, 100)
            ]
        )
        moving = np.linalg.norm(np.diff(body, axis=0), axis=1) * 30 > 0.5  # degrees per second
        starts = np.flatnonzero(moving[1:] & ~moving[:-1]) / 30
        gaps = np.diff(starts)
        assert 8 <= len(starts) <= 40
        assert gaps.min() >= 5.5 and gaps.max() <= 31.0
        assert np.median(gaps) >= 9.0


def test_breath_in_and_lean_before_a_turn_need_the_lookahead(dialogues):
    """Before each turn of self's that follows a silence, the lips part (less than a mouth counts
    as open) and the body leans in; without the anticipation's look-ahead they cannot come early."""
    audio, ref = dialogues["story"]
    onsets = [int(s * 30) for s, _ in ref.self_speech[1:]]
    with_cue = ProceduralGenerator().generate(audio, seed=3)[0]
    without = ProceduralGenerator({"anticipation": 0}).generate(audio, seed=3)[0]
    for k in onsets:
        before = slice(k - 6, k - 1)
        jaw = with_cue.face[before, B["jawOpen"]]
        assert 0.01 < jaw.max() < 0.05
        assert without.face[before, B["jawOpen"]].max() < 0.005
        chin = head_pitch(with_cue)
        assert chin[k - 2] < chin[k - 12] - 0.5  # the chin lifts with the in-breath
