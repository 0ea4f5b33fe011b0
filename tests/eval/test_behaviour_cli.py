"""``convodrive eval behaviour``: JSON figures for a clip and its audio; one-line user errors."""

from __future__ import annotations

import json

import pytest

from convodrive.cli.main import main
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.motion.clip import MotionClip
from convodrive.motion.npz import save_clip
from tests.conftest import run_cli
from tests.procedural_dialogues import make


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("eval")
    wav, audio = make("alternating", d)
    clip = ProceduralGenerator({"phones": False}).generate(audio, seed=0)[0]
    motion = save_clip(clip, d / "motion.npz")
    return wav, motion, clip


def test_eval_behaviour_prints_the_figures(files, capsys):
    wav, motion, _ = files
    assert main(["eval", "behaviour", str(motion), str(wav)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["lip_sync"]["pearson_jaw_vs_self_envelope"] >= 0.6
    assert out["lip_sync"]["jaw_closed_when_self_silent"] >= 0.95
    assert out["head"]["speaking_to_listening_ratio"] >= 2.0
    assert out["activity"]["self_speaking_frames"] > 0 and out["activity"]["only_partner_frames"] > 0


def test_swapped_channels_break_lip_sync(files, capsys):
    wav, motion, _ = files
    assert main(["eval", "behaviour", str(motion), str(wav), "--channels", "1,0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["lip_sync"]["pearson_jaw_vs_self_envelope"] < 0.3
    assert out["lip_sync"]["jaw_closed_when_self_silent"] < 0.9


def test_missing_file_and_length_mismatch_are_one_line_errors(files, tmp_path):
    wav, motion, clip = files
    r = run_cli("eval", "behaviour", str(tmp_path / "nope.npz"), str(wav))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "nope.npz" in r.stderr
    short = save_clip(MotionClip.neutral(clip.num_frames // 2), tmp_path / "short.npz")
    r = run_cli("eval", "behaviour", str(short), str(wav))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "frames" in r.stderr and "Traceback" not in r.stderr
    r = run_cli("eval", "behaviour", str(motion), str(wav), "--channels", "x")
    assert r.returncode == 2 and r.stderr.count("\n") == 1
