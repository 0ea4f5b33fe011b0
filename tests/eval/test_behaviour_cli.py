"""``convodrive eval behaviour``: JSON figures for a clip and its audio; one-line user errors."""

from __future__ import annotations

import json

import pytest

from convodrive.cli.main import main
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.motion.clip import MotionClip
from convodrive.motion.npz import save_clip
from tests.conftest import cli_in_process
from tests.procedural_dialogues import make

pytestmark = [pytest.mark.espeak]


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
    r = cli_in_process("eval", "behaviour", str(tmp_path / "nope.npz"), str(wav))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "nope.npz" in r.stderr
    short = save_clip(MotionClip.neutral(clip.num_frames // 2), tmp_path / "short.npz")
    r = cli_in_process("eval", "behaviour", str(short), str(wav))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "frames" in r.stderr and "Traceback" not in r.stderr
    r = cli_in_process("eval", "behaviour", str(motion), str(wav), "--channels", "x")
    assert r.returncode == 2 and r.stderr.count("\n") == 1


def test_reference_segments_from_json_or_audacity_labels_replace_the_level_detector(files, tmp_path, capsys):
    """Both formats give the same masks; the activity says where it came from."""
    wav, motion, _ = files
    sidecar = wav.with_suffix(".json")
    turns = json.loads(sidecar.read_text())["turns"]
    labels = tmp_path / "labels.txt"
    labels.write_text("".join(f"{t['start']}\t{t['end']}\t{t['speaker']}\n" for t in turns) + "\\\t100\t4000\n")
    outs = []
    for ref in (sidecar, labels):
        assert main(["eval", "behaviour", str(motion), str(wav), "--segments", str(ref)]) == 0
        outs.append(json.loads(capsys.readouterr().out))
    assert outs[0]["activity"]["source"].startswith("reference segments")
    assert {k: v for k, v in outs[0]["activity"].items() if k != "source"} == {
        k: v for k, v in outs[1]["activity"].items() if k != "source"
    }
    speaking = sum(round((t["end"] - t["start"]) * 30) for t in turns if t["speaker"] == "self")
    assert abs(outs[0]["activity"]["self_speaking_frames"] - speaking) <= 4
    assert outs[0]["voice_activity"]["self_on_when_only_partner_speaks"] <= 0.05


@pytest.mark.parametrize(
    "text, problem",
    [
        ("{not json", "not valid JSON"),
        ('{"turns": [{"start": 1, "end": 0.5, "speaker": "self"}]}', "before start"),
        ('[{"start": 0, "end": 1, "speaker": "robot"}]', "not self or partner"),
        ('[{"start": "soon", "end": 1, "speaker": "self"}]', "not a number"),
        ("0.5\t1.0\n", "START<TAB>END<TAB>LABEL"),
        ("[]", "no speech segments"),
    ],
)
def test_bad_segment_files_are_one_line_errors(files, tmp_path, capsys, text, problem):
    wav, motion, _ = files
    bad = tmp_path / "segments.txt"
    bad.write_text(text)
    assert main(["eval", "behaviour", str(motion), str(wav), "--segments", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and problem in err and str(bad) in err
