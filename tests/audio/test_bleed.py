"""Voice activity that survives microphone bleed: each channel's activity decided with the other
channel in view (``audio.bleed``), on espeak-ng dialogues mixed as two microphones in one room."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.analysis import DyadicAnalyzer, FrameBatch
from convodrive.audio.source import DyadicAudio
from convodrive.audio.synth import add_bleed
from tests.procedural_dialogues import make, reference

pytestmark = [pytest.mark.espeak]


@pytest.fixture(scope="module")
def dialogues(tmp_path_factory):
    d = tmp_path_factory.mktemp("bleed")
    out = {}
    for name in ("alternating", "overlap", "story"):
        path, audio = make(name, d)
        out[name] = (audio, *reference(path).masks(audio.num_frames, 30))
    return out


def analyse(self_voice: np.ndarray, other_voice: np.ndarray) -> FrameBatch:
    analyzer = DyadicAnalyzer(phones=False)
    audio = DyadicAudio(self_voice, other_voice)
    parts = [analyzer.push(audio.self_voice, audio.other_voice), analyzer.finish(audio.num_frames)]
    return FrameBatch.concat([p for p in parts if p is not None])


def error_rates(batch: FrameBatch, self_ref: np.ndarray, partner_ref: np.ndarray) -> tuple[float, float]:
    """Self active where only the partner speaks, and the partner active where only self speaks."""
    vad_self, vad_other = batch.self_voice["vad"] > 0, batch.other_voice["vad"] > 0
    return float(vad_self[partner_ref & ~self_ref].mean()), float(vad_other[self_ref & ~partner_ref].mean())


@pytest.mark.parametrize("name", ["alternating", "overlap", "story"])
def test_bleed_at_minus_12_db_is_not_taken_for_the_other_voice(dialogues, name):
    audio, self_ref, partner_ref = dialogues[name]
    clean = analyse(audio.self_voice, audio.other_voice)
    bled = analyse(*add_bleed(audio.self_voice, audio.other_voice, -12.0))
    wrong_self, wrong_partner = error_rates(bled, self_ref, partner_ref)
    assert wrong_self <= 0.05 and wrong_partner <= 0.05, (wrong_self, wrong_partner)
    # Each voice is still heard where it speaks alone, as much as without the bleed (in overlaps
    # the louder voice may mask the other's quieter moments, which turn-long references count).
    for key, ref in (("self_voice", self_ref & ~partner_ref), ("other_voice", partner_ref & ~self_ref)):
        heard_clean = float((getattr(clean, key)["vad"] > 0)[ref].mean())
        heard = float((getattr(bled, key)["vad"] > 0)[ref].mean())
        assert heard >= heard_clean - 0.03 and heard >= 0.9, (key, heard, heard_clean)


def test_a_level_detector_alone_is_fooled_by_the_same_bleed(dialogues):
    """The reason for the two-channel rule: without it, the partner at -12 dB in self's microphone
    sounds like self speaking (the bleed flags are switched off by analysing each channel with a
    silent partner)."""
    audio, self_ref, partner_ref = dialogues["story"]
    bled_self, _ = add_bleed(audio.self_voice, audio.other_voice, -12.0)
    alone = analyse(bled_self, np.zeros_like(bled_self))
    assert float((alone.self_voice["vad"] > 0)[partner_ref & ~self_ref].mean()) > 0.5


def test_clean_recordings_flag_no_bleed(dialogues):
    for audio, _, _ in dialogues.values():
        batch = analyse(audio.self_voice, audio.other_voice)
        assert batch.self_voice["bleed"].mean() < 0.01 and batch.other_voice["bleed"].mean() < 0.01


@pytest.mark.parametrize(
    "self_gain_db, delay_ms",
    [(0.0, 0.0), (9.0, 3.0), (-9.0, 3.0), (0.0, 8.0)],
    ids=["no-delay", "self-mic-hot", "self-mic-quiet", "far-apart"],
)
def test_unbalanced_gains_and_other_delays(dialogues, self_gain_db, delay_ms):
    """A digital cross-feed with no delay is settled by the level difference; microphone gains 9 dB
    apart, where the levels alone would mislead, by which microphone heard the copy later."""
    audio, self_ref, partner_ref = dialogues["alternating"]
    a, b = add_bleed(audio.self_voice, audio.other_voice, -12.0, delay_ms=delay_ms)
    gain = np.float32(10 ** (self_gain_db / 20))
    batch = analyse(np.clip(a * gain, -1, 1), b)
    wrong_self, wrong_partner = error_rates(batch, self_ref, partner_ref)
    assert wrong_self <= 0.05 and wrong_partner <= 0.05, (wrong_self, wrong_partner)
    assert float((batch.self_voice["vad"] > 0)[self_ref].mean()) >= 0.9
