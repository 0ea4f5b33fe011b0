"""The model card a model folder carries: what the weights are, the command and the corpus recipe that
made them, their validation and export figures. It travels with the weights, so it names commands
and a corpus's source, never a folder of the machine that trained them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from convodrive.training.recipe import DataSpec, Recipe


def _train_command(meta: dict[str, Any], corpus: dict[str, Any]) -> str:
    """The ``convodrive train`` that made these weights, the corpus named by its folder's name."""
    train = meta["training"].get("train_config") or {}
    parts = ["convodrive train", meta["model"], "--corpus", str(corpus.get("name") or "CORPUS")]
    parts += ["--preset", str(meta["preset"]), "--stage", str(meta["stage"]), "--steps", str(meta["training"]["steps"])]
    if "seed" in train:
        parts += ["--seed", str(train["seed"])]
    return " ".join(parts)


def _recorded(source: dict[str, Any]) -> list[dict[str, Any]]:
    """A made corpus's sources of recorded speech (all but espeak-ng), each with licence and hours."""
    return [s for s in source.get("sources", ()) if s.get("name") != "espeak-ng"]


def _augmented(runs: dict[str, dict[str, Any]]) -> str:
    """How the stages' training windows were augmented, read from each stage's own run."""
    settings: dict[str, list[str]] = {}
    for stage, run in runs.items():
        train = run.get("train_config") or {}
        if train.get("augment"):
            settings.setdefault(f"--set augment={train['augment']} --set augment_p={train['augment_p']:g}", []).append(
                stage
            )
    return "; ".join(f"`{flags}` ({', '.join(stages)})" for flags, stages in settings.items())


def train_script_corpus(corpus: Path, own_licence: str, runs: dict[str, dict[str, Any]]) -> tuple[str, str]:
    """What a train script's card says of its corpus (``scripts/train_corpus.sh``): how it was made
    and, with ``REAL_VOICES=1``, the recorded voices it heard; how its stages (``runs``: each
    stage's run.json) were augmented; and the licence paragraph, ``own_licence`` when it heard
    none, else one that names each voice's licence (attribution)."""
    source = json.loads((corpus / "manifest.json").read_text()).get("source", {})
    recorded = _recorded(source)
    augmented = _augmented(runs)
    made_with = ", then with `REAL_VOICES=1`: real voices paired in" if recorded else ""
    made_with += f"; training augmented: {augmented}" if augmented else ""
    heard = "".join(f" and {s['name']} ({s['hours']} h)" for s in recorded)
    made = (
        f"made by `scripts/train_corpus.sh` (`convodrive corpus make --hours {source.get('hours')} --seed 0`"
        f"{made_with}; speech by espeak-ng{heard}, motion by convodrive's `procedural` "
        "generator); its test split scores the model below"
    )
    if not recorded:
        return made, own_licence
    licence = (
        "Trained on data this project made (espeak-ng speech, procedural motion) and on recorded voices: "
        + "; ".join(f"{s['name']}, {s['licence']}, {s['hours']} h" for s in recorded)
        + ". No motion or audio of SHOW, BEAT2 or the audio2photoreal data. The weights are under the licence of"
        " convodrive itself; the voices' licences allow commercial use of what is derived, with attribution (given here)."
    )
    return made, licence


def _corpus_text(corpus: dict[str, Any]) -> str:
    """What the corpus is and how to make it again (its manifest's source), never where it lay on
    the machine that trained: a card travels with the weights."""
    if not corpus:
        return "not recorded"
    source = corpus.get("source") or {}
    facts = f"{corpus.get('name', '?')}, {corpus.get('hours', '?')} h, {corpus.get('conversations', '?')} conversations"
    if source.get("kind") == "made":
        recorded = _recorded(source)
        flags = "".join(f" --voices {s['name']}" for s in recorded)  # folder names: how the user named them
        flags += f" --voice-hours {source['voice_hours']}" if recorded and source.get("voice_hours") else ""
        how = f"made by `convodrive corpus make --hours {source.get('hours')} --seed {source.get('seed')} --takes {source.get('takes')}{flags}`"
        sources = "; ".join(
            f"{s['name']} ({s.get('licence', '?')}, {s.get('hours', '?')} h)" for s in source.get("sources", ())
        )
        return f"{facts}; {how} (teacher: the {source.get('generator', '?')} generator)" + (
            f"; sources: {sources}" if sources else ""
        )
    if source.get("kind"):  # imported: its kind and options, not the folder it came from
        flags = f" --speaker {source['speaker']}" if source.get("speaker") else ""
        flags += " --mano FILE" if source.get("mano") else ""
        return f"{facts}; imported by `convodrive corpus import {source['kind']} SRC{flags}`"
    return facts


def model_card(recipe: Recipe, config: Any, spec: DataSpec, meta: dict[str, Any]) -> str:
    training = meta["training"]
    corpus = spec.info.get("corpus", {}) if isinstance(spec.info.get("corpus"), dict) else {}
    lines = [
        f"# Model card: {recipe.name} ({meta['preset']} preset, stage {meta['stage']})",
        "",
        recipe.card(config, spec),
        "",
        "## Training",
        f"- command: `{_train_command(meta, corpus)}`, then `convodrive export RUN`",
        f"- corpus: {_corpus_text(corpus)}",
        f"- steps: {training['steps']}, global batch {training['train_config'].get('batch_size')}, processes {training['world_size']}",
        f"- commit: `{training['commit']}`, torch {training['torch']}",
        f"- licence of the weights: {corpus.get('licence', 'that of the training corpus')}",
        "",
        "## Validation",
        *(f"- {k}: {v:.4g}" for k, v in training["validation"].items()),
        "",
        "## Export",
        "- graphs: " + ", ".join(f"`{g['file']}`" for g in meta["graphs"].values()),
        f"- parity, ONNX Runtime against torch (max abs error, tolerance {meta['parity']['tolerance']:g}):",
        *(
            f"  - {g}: " + ", ".join(f"{s} {e:.2g}" for s, e in errs.items())
            for g, errs in meta["parity"]["max_abs_err"].items()
        ),
    ]
    if meta["int8"]:
        lines.append("- int8 (dynamic, MatMul only); cost against the float graph:")
        lines += [
            f"  - {g}: max abs {c['max_abs_err']:.3g}, relative RMS {c['relative_rms_err']:.3g}"
            for g, c in meta["int8"]["cost"].items()
        ]
        if meta["int8"].get("float"):
            lines.append("- kept float: " + ", ".join(f"`{g}`" for g in meta["int8"]["float"]))
    return "\n".join(lines) + "\n"
