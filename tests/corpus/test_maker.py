"""The bootstrap corpus maker: voices, languages and styles; turn taking; determinism across jobs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from convodrive.audio.source import DyadicAudio
from convodrive.corpus import Corpus
from convodrive.corpus.dialogues import synthesize
from convodrive.corpus.maker import SPEAKERS, make_corpus, plan_corpus
from convodrive.eval.behaviour import GAZE_AT_PARTNER_DEG
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.motion.skeleton import JOINT_INDEX
from tests.conftest import cli_in_process, run_cli


def test_plan_spreads_voices_languages_and_speakers() -> None:
    plans = plan_corpus(2.0, seed=0)
    assert abs(sum(p.seconds for p in plans) - 7200) < 1
    voices = [v for p in plans for v in (p.self_voice, p.partner_voice)]
    assert len({v.variant for v in voices}) >= 8
    assert len({p.speaker.label for p in plans}) >= 4 and len(SPEAKERS) >= 4
    assert len({p.language for p in plans}) >= 4
    pitches, rates = [v.pitch for v in voices], [v.rate for v in voices]
    assert max(pitches) - min(pitches) >= 30 and max(rates) - min(rates) >= 40
    assert plan_corpus(2.0, seed=0) == plans and plan_corpus(2.0, seed=1) != plans
    # A conversation depends on (seed, index) alone: a longer corpus starts with the same ones.
    assert plan_corpus(3.0, seed=0)[: len(plans) - 1] == plans[:-1]


def _silent_stretches(segments: list[list[float]], end: float) -> list[tuple[float, float]]:
    out, t = [], 0.0
    for start, stop in sorted(segments):
        if start > t:
            out.append((t, start))
        t = max(t, stop)
    return out + [(t, end)]


@pytest.mark.espeak
def test_dialogues_have_realistic_turn_taking() -> None:
    plan = plan_corpus(1.0, seed=4)[0]
    dialogue = synthesize((plan.self_voice, plan.partner_voice), 150.0, np.random.default_rng(11))
    summary = dialogue.summary()
    assert 145 < dialogue.duration < 175
    assert summary["backchannels"] >= 3 and summary["turn_overlaps"] >= 1
    sentences = [s for s in dialogue.speech if s.kind == "sentence"]
    in_turn_pauses = [
        b.start - a.end for a, b in zip(sentences, sentences[1:]) if a.channel == b.channel and b.start > a.end
    ]
    assert sum(0.2 <= p <= 0.9 for p in in_turn_pauses) >= 5
    # A long listening stretch: 10 s or more with no sentence from self (backchannels only) while
    # the partner talks through most of it.
    self_sentences = [[x.start, x.end] for x in sentences if x.channel == 0]
    stretches = [(a, b) for a, b in _silent_stretches(self_sentences, dialogue.duration) if b - a >= 10]
    assert stretches
    partner = [(x.start, x.end) for x in sentences if x.channel == 1]
    a, b = stretches[0]
    assert sum(max(0.0, min(e, b) - max(s, a)) for s, e in partner) > 0.5 * (b - a)
    # The audio agrees with the segments: self's channel is silent wherever it has no speech.
    for a, b in _silent_stretches(summary["speech"]["self"], dialogue.duration):
        if b - a > 1.0:
            quiet = dialogue.audio[int(a * 16000) + 800 : int(b * 16000) - 800, 0]
            assert np.sqrt(np.mean(quiet**2)) < 0.003


@pytest.mark.espeak
def test_speaker_styles_move_differently() -> None:
    plan = plan_corpus(1.0, seed=2)[0]
    d = synthesize((plan.self_voice, plan.partner_voice), 30.0, np.random.default_rng(3))
    audio = DyadicAudio(d.audio[:, 0], d.audio[:, 1])
    energy, gaze = {}, {}
    for speaker in SPEAKERS:
        clip = ProceduralGenerator({**speaker.style, "phones": False}).generate(audio, seed=5)[0]
        head = np.diff(clip.pose[:, JOINT_INDEX["head"]], axis=0)
        wrist = np.diff(clip.pose[:, JOINT_INDEX["right_elbow"]], axis=0)
        energy[speaker.label] = (np.abs(head).mean(), np.abs(wrist).mean())
        eye = np.degrees(np.linalg.norm(clip.pose[:, JOINT_INDEX["left_eye_smplhf"]], axis=1))
        away = eye > GAZE_AT_PARTNER_DEG
        gaze[speaker.label] = (away.mean(), eye[away].mean() if away.any() else 0.0)
    assert energy["expansive"][0] > 1.5 * energy["reserved"][0]
    assert energy["animated"][1] > 1.5 * energy["calm"][1]  # gestures on versus off
    # They look at the partner differently: how often they look away, and how far.
    assert gaze["restless"][0] > 2.0 * gaze["steady"][0]
    assert gaze["expansive"][1] > 1.5 * gaze["reserved"][1]


@pytest.mark.espeak
def test_make_is_deterministic_whatever_the_jobs(tmp_path: Path) -> None:
    a = make_corpus(0.012, tmp_path / "a", ProceduralGenerator, seed=9, jobs=1)
    result = run_cli("corpus", "make", "--hours", "0.012", "--out", str(tmp_path / "b"), "--seed", "9", "--jobs", "2")
    assert result.returncode == 0, result.stderr
    assert "min per corpus hour" in result.stdout and "load average" in result.stdout
    assert a.conversations >= 1 and abs(a.hours - 0.012) < 0.002
    ca, cb = Corpus.open(tmp_path / "a"), Corpus.open(tmp_path / "b")
    assert [c.to_json() for c in ca.conversations] == [c.to_json() for c in cb.conversations]
    for conv in ca.conversations:
        takes_a, takes_b = ca.takes(conv.id), cb.takes(conv.id)
        assert len(takes_a) == conv.takes == 4
        for x, y in zip(takes_a, takes_b):
            np.testing.assert_array_equal(x.pose, y.pose)
            np.testing.assert_array_equal(x.face, y.face)
        np.testing.assert_array_equal(ca.mel(conv.id), cb.mel(conv.id))
        assert (tmp_path / "a" / conv.audio).read_bytes() == (tmp_path / "b" / conv.audio).read_bytes()
        # Takes differ: the one-to-many structure the models learn.
        assert np.abs(takes_a[0].pose - takes_a[1].pose).max() > 0.01
        assert conv.speaker in {s.label for s in SPEAKERS}
        style = next(s.style for s in SPEAKERS if s.label == conv.speaker)
        assert conv.metadata["style"] == {**style, "phones": conv.metadata["language"].startswith("en")}
        assert {"language", "voices", "speech", "take_seeds"} <= set(conv.metadata)
    assert list(ca.check()) == ca.conversations
    manifest = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert manifest["source"]["kind"] == "made" and manifest["source"]["seed"] == 9
    assert manifest["licence"].startswith("no third-party data")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--hours", "0"], "nothing to make (give --hours above 0, --voices or --conversations)"),
        ([], "corpus make: give --hours (espeak-ng conversation), --voices or --conversations"),
        (["--hours", "nan"], "--hours: expected a number from 0 to 1000"),
        (["--hours", "1", "--jobs", "0"], "--jobs: expected a whole number from 1 to 256"),
        (["--hours", "1", "--takes", "99"], "--takes: expected a whole number from 1 to 16"),
    ],
)
def test_bad_make_options_are_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    result = cli_in_process("corpus", "make", "--out", str(tmp_path / "c"), *args)
    assert result.returncode == 2 and message in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "c").exists()


def test_make_refuses_a_folder_in_use_and_touches_nothing(tmp_path: Path) -> None:
    (tmp_path / "mine.txt").write_text("keep")
    result = cli_in_process("corpus", "make", "--hours", "0.01", "--out", str(tmp_path))
    assert result.returncode == 2 and "not an empty folder" in result.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]


def test_the_recorded_style_and_seed_remake_the_teachers_take(tmp_path: Path) -> None:
    """eval compare scores the teacher with the options the corpus recorded: they must be all of them."""
    import soundfile

    from convodrive.audio.source import DyadicAudio

    make_corpus(
        0.006, tmp_path / "c", ProceduralGenerator, seed=1, jobs=1
    )  # one Italian conversation: no phone decoder
    corpus = Corpus.open(tmp_path / "c")
    conv = corpus.conversations[0]
    assert conv.metadata["language"] == "it" and conv.metadata["style"]["phones"] is False
    audio, _ = soundfile.read(tmp_path / "c" / conv.audio, dtype="float32")
    again = ProceduralGenerator(conv.metadata["style"]).generate(
        DyadicAudio(audio[:, 0], audio[:, 1]), seed=conv.metadata["take_seeds"][0]
    )[0]
    stored = corpus.takes(conv.id)[0]
    np.testing.assert_allclose(again.face, stored.face, atol=2e-3)
    np.testing.assert_allclose(again.pose, stored.pose, atol=2e-3)
