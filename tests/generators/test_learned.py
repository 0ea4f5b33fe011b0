"""Learned generators: a third-party model trained, exported and driven; the run loads no torch;
streaming equals offline generation for a seed, whatever the chunking."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import REPO, require, run_cli
from tests.corpora import dyadic_audio

pytestmark = [require("torch"), require("onnxruntime"), pytest.mark.build_tools]


@pytest.fixture(scope="module")
def tiny_model(plugin_site: Path, tiny_corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tests/plugin_pkg's tiny_regressor, trained for a few steps and exported."""
    root = tmp_path_factory.mktemp("tiny_model")
    env = {"PYTHONPATH": str(plugin_site)}
    trained = run_cli(
        "train", "tiny_regressor", "--corpus", str(tiny_corpus), "--no-progress", "--out", str(root / "run"), env=env
    )
    assert trained.returncode == 0, trained.stderr
    exported = run_cli("export", str(root / "run"), "--out", str(root / "model"), env=env)
    assert exported.returncode == 0, exported.stderr
    return root / "model"


PROBE = """
import json, sys
from convodrive.cli.main import main
rc = main(sys.argv[1:])
loaded = sorted(m for m in sys.modules if m == "torch" or m.startswith("torch."))
print(json.dumps({"rc": rc, "torch": loaded, "onnxruntime": "onnxruntime" in sys.modules}))
"""


def test_a_drive_with_a_learned_generator_loads_no_torch(tiny_model: Path, plugin_site: Path, tmp_path: Path) -> None:
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            PROBE,
            "drive",
            str(REPO / "samples" / "dialogue.wav"),
            "--generator",
            "tiny_learned",
            "-G",
            f"model={tiny_model}",
            "--backend",
            "record",
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**__import__("os").environ, "PYTHONPATH": str(plugin_site)},
    )
    assert result.returncode == 0, result.stderr
    probe = json.loads(result.stdout.strip().splitlines()[-1])
    assert probe == {"rc": 0, "torch": [], "onnxruntime": True}
    from convodrive.audio.source import AudioSource
    from convodrive.motion.npz import load_clip

    clip = load_clip(tmp_path / "out" / "motion.npz")
    assert clip.num_frames == AudioSource(REPO / "samples" / "dialogue.wav").info.num_motion_frames
    assert clip.pose.std(axis=0).max() > 0  # the network's output moves


def test_stream_equals_generate_for_any_chunking(tiny_model: Path, plugin_site: Path) -> None:
    sys.path.insert(0, str(plugin_site))
    try:
        from convodrive_tiny_plugin.learned import TinyLearnedGenerator
    finally:
        sys.path.remove(str(plugin_site))
    audio = dyadic_audio(3.3)
    gen = TinyLearnedGenerator({"model": str(tiny_model)})
    assert gen.lookahead_frames == 30 - 6 - 1 + 1
    offline = gen.generate(audio, seed=3, num_samples=2)
    assert offline[0].num_frames == audio.num_frames == 99
    for chunk in (160, 1600, 7777):
        frames = list(gen.stream(audio.chunks(chunk), seed=3))
        assert len(frames) == 99
        np.testing.assert_array_equal(np.stack([f.pose for f in frames]), offline[0].pose)
        np.testing.assert_array_equal(np.stack([f.face for f in frames]), offline[0].face)
        assert [round(f.time * 30) for f in frames] == list(range(99))
    assert np.abs(offline[0].pose - offline[1].pose).max() > 1e-3  # takes differ by seed
    again = gen.generate(audio, seed=3)[0]
    np.testing.assert_array_equal(again.pose, offline[0].pose)


def test_a_folder_of_another_model_is_one_line(tiny_model: Path, plugin_site: Path, tmp_path: Path) -> None:
    meta = json.loads((tiny_model / "model.json").read_text())
    other = tmp_path / "other"
    other.mkdir()
    for name in meta["files"]:
        (other / name).write_bytes((tiny_model / name).read_bytes())
    meta["model"] = "probtalk"
    (other / "model.json").write_text(json.dumps(meta))
    out = run_cli(
        "drive",
        str(REPO / "samples" / "dialogue.wav"),
        "--generator",
        "tiny_learned",
        "-G",
        f"model={other}",
        "--backend",
        "record",
        "--out",
        str(tmp_path / "o"),
        env={"PYTHONPATH": str(plugin_site)},
    )
    assert out.returncode == 2 and "holds a 'probtalk' model" in out.stderr and len(out.stderr.splitlines()) == 1
