"""Model cards and model.json travel with the weights: they name the command and the corpus's recipe,
never a folder of the machine that trained them."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.conftest import REPO

# A path from the root or a home folder, where a token starts: `/work/x`, (/tmp/x), ~/x, C:\x.
MACHINE_PATH = re.compile(r"""(?:^|[\s`'"(=\[,])((?:~|/[\w.-]+)/[^\s`'")\],]*|[A-Za-z]:\\\S*)""", re.M)


def machine_paths(text: str) -> list[str]:
    return MACHINE_PATH.findall(text)


def test_the_pattern_finds_machine_paths_and_leaves_figures_alone() -> None:
    assert machine_paths("- corpus: `/work/corpus2h` (corpus2h)") == ["/work/corpus2h"]
    assert machine_paths("run (/tmp/x/run) and ~/runs/a and C:\\data\\c") == ["/tmp/x/run", "~/runs/a", "C:\\data\\c"]
    assert machine_paths("1/30 s, FD_g/Div_k, https://example.org/a, `scripts/train_a2p.sh corpus2h a2p`") == []


def _shipped_cards() -> list[Path]:
    cards = sorted(p for p in (REPO / "convodrive").rglob("*.md") if (p.parent / "model.json").is_file())
    assert {p.parent.name for p in cards} >= {"model", "fgd_model"} and len(cards) >= 3, cards
    return cards


@pytest.mark.parametrize("card", _shipped_cards(), ids=lambda p: str(p.parent.relative_to(REPO)))
def test_no_shipped_card_names_a_folder_of_the_machine_that_trained_it(card: Path) -> None:
    text = card.read_text(encoding="utf-8")
    assert machine_paths(text) == []
    assert "- command: `convodrive train " in text
    assert re.search(r"^- corpus: [\w.-]+, ", text, re.MULTILINE)  # the corpus by its folder's name


@pytest.mark.torch
@pytest.mark.parametrize(
    "source, says",
    [
        (
            {"kind": "made", "hours": 2.0, "seed": 0, "takes": 4, "generator": "procedural"},
            "made by `convodrive corpus make --hours 2.0 --seed 0 --takes 4` (teacher: the procedural generator)",
        ),
        (
            {
                "kind": "made",
                "hours": 1.0,
                "seed": 2,
                "takes": 4,
                "generator": "procedural",
                "voice_hours": 0.5,
                "sources": [
                    {"name": "espeak-ng", "licence": "no third-party data", "hours": 1.0},
                    {"name": "librivox", "licence": "Public domain", "hours": 0.5},
                ],
            },
            "made by `convodrive corpus make --hours 1.0 --seed 2 --takes 4 --voices librivox --voice-hours 0.5` "
            "(teacher: the procedural generator); sources: espeak-ng (no third-party data, 1.0 h); "
            "librivox (Public domain, 0.5 h)",
        ),
        (
            {"kind": "beat2", "from": "/home/someone/BEAT2", "speaker": "wayne", "mano": "/tmp/mano.npz"},
            "imported by `convodrive corpus import beat2 SRC --speaker wayne --mano FILE`",
        ),
    ],
)
def test_export_writes_the_command_and_the_corpus_recipe_not_its_folder(source: dict, says: str) -> None:
    from convodrive.training.model_card import model_card

    corpus = {"path": "/work/corpus2h", "name": "corpus2h", "hours": 2.046, "conversations": 67, "source": source}
    spec = SimpleNamespace(info={"corpus": corpus})
    recipe = SimpleNamespace(name="fgd", card=lambda config, spec: "An FGD embedder.")
    meta = {
        "model": "fgd",
        "preset": "small",
        "stage": "main",
        "training": {
            "corpus": "/work/corpus2h",
            "checkpoint": "/work/runs/fgd/checkpoints/step-00000010",
            "steps": 10,
            "train_config": {"batch_size": 4, "seed": 3},
            "world_size": 1,
            "commit": "abc",
            "torch": "2.13.0",
            "validation": {"loss": 0.5},
        },
        "graphs": {"encoder": {"file": "encoder.onnx"}},
        "parity": {"tolerance": 1e-4, "max_abs_err": {"encoder": {"size=1": 1e-6}}},
        "int8": None,
    }
    card = model_card(recipe, None, spec, meta)  # type: ignore[arg-type]
    assert machine_paths(card) == []
    assert "- command: `convodrive train fgd --corpus corpus2h --preset small --stage main --steps 10 --seed 3`" in card
    assert f"- corpus: corpus2h, 2.046 h, 67 conversations; {says}" in card


@pytest.mark.parametrize("card", _shipped_cards(), ids=lambda p: str(p.parent.relative_to(REPO)))
def test_no_shipped_model_json_names_a_folder_of_the_machine(card: Path) -> None:
    assert machine_paths((card.parent / "model.json").read_text(encoding="utf-8")) == []


def test_a_train_scripts_card_names_the_recorded_voices_and_their_licences(tmp_path: Path) -> None:
    """scripts/train_{probtalk,a2p}.sh: espeak-ng only keeps the script's own licence paragraph;
    with REAL_VOICES=1 the corpus line and the licence name each voice, its licence and hours."""

    from convodrive.training.model_card import train_script_corpus

    espeak = {"name": "espeak-ng", "licence": "no third-party data", "hours": 2.0}
    voice = {"name": "asterisk-it", "licence": "CC-BY-3.0 (Carlo Flora)", "hours": 0.5}
    for sources in ([espeak], [espeak, voice]):
        (tmp_path / "manifest.json").write_text(
            json.dumps({"source": {"kind": "made", "hours": 2, "sources": sources}})
        )
        augmented = len(sources) > 1
        runs = {  # each stage's run.json: the PQ-VAE hears no audio, so it is never augmented
            "vq": {"train_config": {"augment": "", "augment_p": 0.5}},
            "predictor": {"train_config": {"augment": "all" if augmented else "", "augment_p": 0.2}},
        }
        made, licence = train_script_corpus(tmp_path, "OWN", runs)
        assert made.startswith("made by `scripts/train_corpus.sh` (`convodrive corpus make --hours 2 --seed 0`")
        assert machine_paths(made + licence) == []
        if not augmented:
            assert "REAL_VOICES" not in made and "asterisk" not in made and "augment" not in made and licence == "OWN"
        else:
            assert "REAL_VOICES=1" in made and "espeak-ng and asterisk-it (0.5 h)" in made
            assert "training augmented: `--set augment=all --set augment_p=0.2` (predictor)" in made
            assert "asterisk-it, CC-BY-3.0 (Carlo Flora), 0.5 h" in licence and "attribution" in licence


def test_train_corpus_refuses_a_made_corpus_without_the_real_voices_asked_for(tmp_path: Path) -> None:
    script = REPO / "scripts" / "train_corpus.sh"
    espeak = {"name": "espeak-ng", "licence": "own", "hours": 2.0}
    (tmp_path / "manifest.json").write_text(json.dumps({"source": {"kind": "made", "sources": [espeak]}}))
    reused = subprocess.run([str(script), str(tmp_path)], capture_output=True, text=True, env=_env(REAL_VOICES="0"))
    assert reused.returncode == 0 and reused.stderr == ""
    refused = subprocess.run([str(script), str(tmp_path)], capture_output=True, text=True, env=_env(REAL_VOICES="1"))
    assert refused.returncode == 1
    assert (
        refused.stderr.strip()
        == f"train_corpus: {tmp_path} holds a corpus made without REAL_VOICES=1; give another folder"
    )


def _env(**extra: str) -> dict[str, str]:
    return {**os.environ, **extra}
