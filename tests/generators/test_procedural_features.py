"""Speech features (loudness, voice activity, F0, accents, syllables, laughter, phones) and the
face and pose conventions the procedural generator relies on."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.analysis import DyadicAnalyzer, FrameBatch
from convodrive.audio.source import DyadicAudio
from convodrive.audio.synth import speak
from convodrive.audio.visemes import VISEME_INDEX, phone_viseme
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.generators.procedural.face import EYE_YAW_MAX, JAW_MAX_RAD
from convodrive.generators.procedural.poses import rest_pose
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.rotations import axis_angle_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX as J
from convodrive.motion.skeleton import forward_kinematics

SR = 16000


def analyse(
    self_voice: np.ndarray, other: np.ndarray | None = None, phones: bool = False, chunk: int = 10**9
) -> FrameBatch:
    other = np.zeros_like(self_voice) if other is None else other
    an = DyadicAnalyzer(phones=phones)
    parts = [an.push(self_voice[i : i + chunk], other[i : i + chunk]) for i in range(0, len(self_voice), chunk)]
    parts.append(an.finish(int(round(len(self_voice) / SR * 30))))
    return FrameBatch.concat([p for p in parts if p is not None])


def voiced_tone(f0: np.ndarray, amp: np.ndarray) -> np.ndarray:
    """A buzzy harmonic tone following per-sample F0 and amplitude, like a sustained vowel."""
    phase = 2 * np.pi * np.cumsum(f0) / SR
    return (amp * sum(np.sin(h * phase) / h for h in range(1, 8))).astype(np.float32)


def pad(x: np.ndarray, before: float = 0.5, after: float = 0.5) -> np.ndarray:
    return np.concatenate([np.zeros(int(before * SR), np.float32), x, np.zeros(int(after * SR), np.float32)])


def test_f0_and_voice_activity_with_hysteresis():
    n = int(1.0 * SR)
    x = pad(voiced_tone(np.full(n, 150.0), np.full(n, 0.2)), 0.5, 1.0)
    s = analyse(x).self_voice
    frames = np.arange(len(s["db"]))
    inside = (frames >= 18) & (frames < 42)
    assert np.all(s["vad"][inside] == 1)
    assert np.all(s["vad"][:14] == 0)
    # Activity holds for a hangover of about 250 ms after the voice stops, then ends.
    assert s["vad"][47] == 1 and np.all(s["vad"][56:] == 0)
    assert np.median(s["f0"][inside]) == pytest.approx(150.0, rel=0.03)
    assert np.all(s["voiced"][inside] == 1)
    assert s["env"][inside].mean() > 0.5 and s["env"][:10].max() == 0.0


def test_pitch_rise_is_an_accent_and_loudness_bursts_are_syllables():
    t = np.arange(int(2.0 * SR)) / SR
    f0 = np.where((t > 1.0) & (t < 1.25), 210.0, 120.0)
    amp = 0.05 + 0.2 * (np.sin(2 * np.pi * 4.0 * t) > 0)  # four syllables a second
    s = analyse(pad(voiced_tone(f0, amp))).self_voice
    accents = np.flatnonzero(s["accent"] > 0) / 30.0 - 0.5
    assert len(accents) >= 1 and np.any((accents > 0.95) & (accents < 1.35))
    nuclei = np.flatnonzero(s["nucleus"] > 0)
    assert 6 <= len(nuclei) <= 9  # about 4 per second over 2 s
    assert np.all(np.diff(nuclei) >= 4)


@pytest.mark.espeak
def test_laughter_is_found_in_ha_ha_not_in_speech():
    laugh = analyse(pad(speak("ha ha ha ha ha ha ha", rate=200, pitch=80) * 0.5)).self_voice["laugh"]
    speech = analyse(
        pad(speak("The weather is nice today and we could go for a walk in the park later.") * 0.5)
    ).self_voice["laugh"]
    assert laugh.max() > 0.9
    assert speech.max() == 0.0


@pytest.mark.pocketsphinx
@pytest.mark.espeak
def test_phones_give_bilabial_visemes_for_p_and_m():
    closed = 0
    for text in (
        "Peter picked a purple pepper. Mama made bubbly maple pie.",
        "Bob bought a map, maybe by mistake.",
        "My mom met a moose in the moonlight by the pump.",
    ):
        batch = analyse(pad(speak(text, rate=140) * 0.5), phones=True)
        speaking = batch.self_voice["vad"] > 0
        assert batch.from_phones[speaking].mean() > 0.5
        top = batch.visemes.argmax(axis=1)
        closed += int(np.sum(top[batch.from_phones] == VISEME_INDEX["PP"]))
    assert closed >= 8  # lips closed on some of the 20-odd bilabials (streaming decisions, 100 ms look-ahead)
    assert phone_viseme("M") == phone_viseme("B") == VISEME_INDEX["PP"] and phone_viseme("+NSN+") == 0


@pytest.mark.pocketsphinx
@pytest.mark.espeak
def test_analysis_is_the_same_for_any_chunking():
    x = pad(speak("Chunks of any size give the same features.") * 0.5)
    other = np.roll(x, 9000)
    a, b = analyse(x, other, phones=True), analyse(x, other, phones=True, chunk=333)
    for key in a.self_voice:
        assert np.array_equal(a.self_voice[key], b.self_voice[key]), key
        assert np.array_equal(a.other_voice[key], b.other_voice[key]), key
    assert np.array_equal(a.visemes, b.visemes)


def test_rest_pose_is_a_relaxed_conversational_pose_not_a_t_pose():
    _, pos = forward_kinematics(axis_angle_to_matrix(rest_pose()))
    for side in ("left", "right"):
        shoulder, elbow, wrist = (pos[J[f"{side}_{j}"]] for j in ("shoulder", "elbow", "wrist"))
        assert elbow[1] < shoulder[1] - 0.15  # upper arm hangs down
        assert wrist[2] > shoulder[2] + 0.15  # forearm forward: elbow bent
        assert abs(wrist[0]) < 0.4 and wrist[1] < shoulder[1]
    assert np.allclose(pos[J["left_wrist"]] * [-1, 1, 1], pos[J["right_wrist"]], atol=1e-9)  # symmetric


@pytest.mark.espeak
def test_jaw_and_eye_joints_agree_with_their_blendshapes():
    x = pad(speak("Look at me while I am talking to you, please.") * 0.5, 0.5, 2.0)
    reply = speak("Sure, go on.") * 0.5
    other = np.zeros_like(x)
    other[len(x) - len(reply) - SR // 4 : len(x) - SR // 4] = reply
    audio = DyadicAudio(x, other)
    clip = ProceduralGenerator().generate(audio, seed=3)[0]
    jaw = clip.face[:, B["jawOpen"]]
    assert jaw.max() > 0.3
    np.testing.assert_allclose(clip.pose[:, J["jaw"], 0], jaw * JAW_MAX_RAD, atol=1e-5)
    assert np.all(clip.pose[:, J["jaw"], 1:] == 0)
    eye = clip.pose[:, J["left_eye_smplhf"]]
    looking_left = clip.face[:, B["eyeLookOutLeft"]]
    assert np.abs(eye).max() > 0.05
    yaw = eye[:, 1]
    np.testing.assert_allclose(np.clip(yaw / EYE_YAW_MAX, 0, 1), looking_left, atol=0.02)
    np.testing.assert_allclose(clip.face[:, B["eyeLookInRight"]], looking_left, atol=1e-6)
    assert np.array_equal(clip.pose[:, J["left_eye_smplhf"]], clip.pose[:, J["right_eye_smplhf"]])
    blink = clip.face[:, B["eyeBlinkLeft"]]
    assert blink.max() > 0.9 and np.mean(blink > 0.5) < 0.2


@pytest.mark.espeak
def test_smile_on_laughter_and_brows_on_accents():
    gen = ProceduralGenerator({"phones": False})
    laugh = pad(speak("ha ha ha ha ha ha ha", rate=200, pitch=80) * 0.5, 0.5, 1.0)
    clip = gen.generate(DyadicAudio(laugh, np.zeros_like(laugh)), seed=0)[0]
    assert clip.face[:, B["mouthSmileLeft"]].max() > 0.3
    speech = pad(speak("The weather is nice today and we could go for a walk in the park later.") * 0.5)
    clip = gen.generate(DyadicAudio(speech, np.zeros_like(speech)), seed=0)[0]
    assert clip.face[:, B["mouthSmileLeft"]].max() < 0.15

    t = np.arange(int(2.0 * SR)) / SR
    tone = pad(voiced_tone(np.where((t > 1.0) & (t < 1.25), 210.0, 120.0), np.full(len(t), 0.2)))
    clip = gen.generate(DyadicAudio(tone, np.zeros_like(tone)), seed=0)[0]
    brow = clip.face[:, B["browInnerUp"]]
    peak = np.argmax(brow) / 30.0 - 0.5
    assert brow.max() > 0.1 and 1.0 < peak < 1.8


@pytest.mark.espeak
def test_backchannel_nods_at_the_partners_pauses():
    parts, pauses = [np.zeros(SR // 2, np.float32)], []
    for text in (
        "I went to the market this morning to buy some fruit.",
        "They had wonderful apples and some very ripe pears.",
        "Then I met our neighbour, who told me about her garden.",
        "She grows tomatoes and beans every summer.",
    ):
        parts.append(speak(text, "en-gb", 170) * 0.5)
        pauses.append(sum(len(p) for p in parts) / SR)
        parts.append(np.zeros(int(0.9 * SR), np.float32))
    other = np.concatenate(parts)
    clip = ProceduralGenerator({"phones": False}).generate(DyadicAudio(np.zeros_like(other), other), seed=0)[0]
    pitch = clip.pose[:, J["head"], 0]
    baseline = np.median(pitch)
    nods = sum(pitch[int(p * 30) : int((p + 1.5) * 30)].max() - baseline > np.radians(1.0) for p in pauses[:-1])
    assert nods >= 2
    assert np.all(clip.face[:, B["jawOpen"]] == 0)


def test_closed_form_head_rotation_matches_the_euler_conversion():
    from convodrive.generators.procedural.body import yxz_axis_angle
    from convodrive.motion.rotations import euler_to_axis_angle

    angles = np.random.default_rng(0).uniform(-3.0, 3.0, (500, 3))
    np.testing.assert_allclose(
        axis_angle_to_matrix(yxz_axis_angle(angles)),
        axis_angle_to_matrix(euler_to_axis_angle(angles, "YXZ")),
        atol=1e-12,
    )


@pytest.mark.pocketsphinx
def test_phone_model_is_cut_down_to_the_viseme_phones(tmp_path):
    from convodrive.audio import phones

    model = phones.viseme_model()
    rows = [line.split() for line in (model / "mdef").read_text().splitlines()[9:]]
    assert sorted(r[0] for r in rows) == sorted(phones.VISEME_PHONES)
    assert [int(x) for r in rows for x in r[6:9]] == list(range(3 * len(rows)))  # senones renumbered
    raw = (model / "means").read_bytes()
    end = raw.index(b"endhdr\n") + 7
    assert np.frombuffer(raw[end : end + 16], "<i4").tolist() == [0x11223344, len(rows), 3, phones.DENSITIES]
    # A model laid out differently is refused (the caller then keeps the full model).
    for name in ("means", "variances", "sendump"):
        (tmp_path / name).write_bytes(b"\0" * 64)
    with pytest.raises(ValueError):
        phones._write_reduced_model(tmp_path, tmp_path / "out", phones.VISEME_PHONES)
