"""Every shipped generator on a real two-voice dialogue of speakers held out of training
(tests/real_voices.py), measured with eval.behaviour against the true turns (issue 32, item 5).

Asserted for every generator, on clean audio and with -12 dB bleed both ways (the learned models'
weights learned recorded voices, bleed among the augmentations), at the targets. a2p meets the
bleed's 97 % of shut frames where only the partner speaks since its face's guidance went from 2 to
1.5 (``GUIDANCE_FACE``: 98.3 % on the worst of four dialogues, 96.2 % at 2; its weights before
these: 15 %).
"""

from __future__ import annotations

import json

import pytest

from bench.bench_real_voices import TARGETS, named_generators
from bench.bench_real_voices import figures as real_voice_figures
from convodrive.audio.source import DyadicAudio
from convodrive.audio.synth import add_bleed
from tests.conftest import require

pytestmark = [require("onnxruntime")]

JAW_R, SHUT_SILENT, SHUT_PARTNER, HEAD_RATIO = (
    TARGETS[k] for k in ("jaw_r", "shut_self_silent", "shut_only_partner", "head_talk_listen")
)


def _generator(name: str):  # noqa: ANN202
    if name == "procedural":
        from convodrive.generators.procedural import ProceduralGenerator

        return ProceduralGenerator()
    if name == "probtalk":
        from convodrive.generators.probtalk.generator import ProbTalkGenerator

        return ProbTalkGenerator()
    from convodrive.generators.a2p.generator import A2PGenerator

    return A2PGenerator()


def _figures(name: str, audio: DyadicAudio, truth: object) -> dict[str, float]:
    return real_voice_figures(_generator(name), audio, truth, seed=0)


@pytest.mark.parametrize("name", ["procedural", "probtalk", "a2p"])
def test_every_generator_on_real_voices(name: str, real_dialogue) -> None:  # noqa: ANN001
    d = real_dialogue
    assert d.truth.self_speech and d.truth.partner_speech  # both real voices speak
    clean = _figures(name, d.audio, d.truth)
    bled = DyadicAudio(*add_bleed(d.audio.self_voice, d.audio.other_voice, -12.0))
    bleed = _figures(name, bled, d.truth)
    print(f"real voices, {name}: " + json.dumps({"clean": clean, "bleed_-12dB": bleed}))
    assert clean["jaw_r"] >= JAW_R
    assert clean["shut_self_silent"] >= SHUT_SILENT and clean["shut_only_partner"] >= SHUT_PARTNER
    assert clean["head_talk_listen"] >= HEAD_RATIO
    assert bleed["jaw_r"] >= JAW_R
    assert bleed["shut_self_silent"] >= SHUT_SILENT
    assert bleed["shut_only_partner"] >= SHUT_PARTNER
    assert bleed["head_talk_listen"] >= HEAD_RATIO


def test_a_variants_values_keep_their_types() -> None:
    """``--variant NAME=GENERATOR:KEY=VALUE``: a boolean or a number reaches the generator as one
    (the options refuse the text 'false' for a bool)."""
    made = named_generators("", [], ["still=procedural:gestures=false,expressiveness=0.5"])
    assert made["still"].options.gestures is False
    assert made["still"].options.expressiveness == 0.5
