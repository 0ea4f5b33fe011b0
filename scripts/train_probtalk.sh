#!/usr/bin/env bash
# Reproduce the ProbTalk weights shipped in convodrive/generators/probtalk/model/ from a fresh clone:
# a 2-hour bootstrap corpus with half an hour of recorded voices paired in, the `probtalk` recipe's
# `small` preset in its three stages (vq, predictor, refiner), an ONNX export (int8 only where it
# costs under 5 % on FGD holistic and under 20 % on FD_k body, which FGD barely sees: see
# train_a2p.sh), a comparison with knn and random on the corpus's test split, and the model card.
#
#   scripts/setup.sh --dev && scripts/train_probtalk.sh [CORPUS_DIR] [RUN_DIR]
#
# The corpus is made unless CORPUS_DIR already holds one; FGD uses the embedder shipped in
# convodrive/eval/fgd_model/ (made by scripts/train_fgd.sh when missing) or FGD_MODEL=DIR. Sized
# for at most 2 hours on 2 idle CPU cores: with two torch threads a step takes 0.42 s (vq),
# 0.20 s (predictor) and 0.27 s (refiner), about 90 minutes of training; with one thread 0.59,
# 0.30 and 0.38 s, 132 minutes. torch uses CUDA when it sees a GPU (--device auto). THREADS
# (default: the machine's cores) sets torch's CPU threads: on a busy machine one thread is fastest
# (two threads that wait for each other in every operation ran ten times slower here). A second
# run resumes each stage where it stopped.
# SHIP_ONLY=1 trains nothing (RUN_DIR's stages are done): it exports, compares and ships;
# TRAIN_ONLY=1 stops after training (train on a GPU machine, ship where the corpus's audio is).
# REAL_VOICES=1, the default (see scripts/train_corpus.sh), mixes real recorded voices into the corpus
# (CORPUS_DIR default corpus2hrv) and augments every stage that hears audio (scripts/real_voices_recipe.sh);
# the card then lists the voices and their licences. REAL_VOICES=0 trains on
# espeak-ng alone, unaugmented (CORPUS_DIR default corpus2h, the weights shipped before these).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/real_voices_recipe.sh  # REAL_VOICES, default_corpus, augment
corpus=${1:-$default_corpus}
runs=${2:-runs/probtalk-small}
threads=${THREADS:-$(nproc)}
bin=.venv/bin
model=convodrive/generators/probtalk/model
started=$(date +%s)
scripts/train_corpus.sh "$corpus"

source scripts/probtalk_stage.sh  # train STAGE STEPS [ARGS...]
if [ "${SHIP_ONLY:-0}" != 1 ]; then
    train vq 8000
    # 16000 steps scored FGD holistic 25.0 against 31.9 but no better FD_g body (the card's Still open)
    train predictor 8000 --init "$runs/vq"
    train refiner 1500 --init "$runs/predictor"
fi
if [ "${TRAIN_ONLY:-0}" = 1 ]; then echo "train_probtalk: trained in $runs (TRAIN_ONLY: nothing exported)"; exit 0; fi
trained=$(date +%s)

rm -rf "$runs/fp32" "$runs/int8"
"$bin/convodrive" export "$runs/refiner" --out "$runs/fp32"
"$bin/convodrive" export "$runs/refiner" --out "$runs/int8" --int8
fgd=${FGD_MODEL:-convodrive/eval/fgd_model}
[ -f "$fgd/model.json" ] || scripts/train_fgd.sh "$corpus"
"$bin/convodrive" eval compare --corpus "$corpus" --split test --samples 4 --seed 0 --fgd-model "$fgd" \
    --generators probtalk,probtalk-int8=probtalk,knn,random \
    -G "probtalk.model=$runs/fp32" -G "probtalk-int8.model=$runs/int8" --out "$runs/compare"

# The chosen folder replaces the shipped one whole (written beside it, then renamed), with the
# card's last section: how it was made, what it scores, what it may be used for.
"$bin/python" - "$runs" "$model" "$corpus" "$started" "$trained" <<'EOF'
import json, os, platform, shutil, subprocess, sys, time
from pathlib import Path

from convodrive.training.model_card import train_script_corpus

runs, model, corpus, started, trained = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], *map(int, sys.argv[4:6])
table = json.loads((runs / "compare" / "compare.json").read_text())
results = table["results"]
GATES = {"FGD holistic": 0.05, "FD_k body": 0.20}  # the most int8 may cost against fp32, per figure
costs = {figure: results["probtalk-int8"][figure] / results["probtalk"][figure] - 1 for figure in GATES}
chosen = "int8" if all(costs[figure] < bound for figure, bound in GATES.items()) else "fp32"
tmp = model.with_name(model.name + ".partial")
shutil.rmtree(tmp, ignore_errors=True)
shutil.copytree(runs / chosen, tmp)
size = sum(f.stat().st_size for f in tmp.iterdir()) / 2**20
if size > 20:
    sys.exit(f"train_probtalk: the {chosen} model is {size:.1f} MiB, more than the 20 MiB the package ships")
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
columns = ["FGD holistic", "FD_g body", "FD_g face", "Var body", "Var face", "BC", "lip r", "mouth shut"]
cell = lambda v: "—" if v is None else f"{v:.3g}"
rows = [f"| {m} | " + " | ".join(cell(r.get(c)) for c in columns) + " |" for m, r in results.items()]
stages = {s: json.loads((runs / s / "run.json").read_text()) for s in ("vq", "predictor", "refiner")}
steps = {s: run["train_config"]["steps"] for s, run in stages.items()}
where = ", ".join(sorted({f"{run['device']} (torch {run['torch']})" for run in stages.values()}))
env = "".join(f"{k}={v} " for k, v in sorted(os.environ.items()) if k in ("SHIP_ONLY", "THREADS", "REAL_VOICES", "VOICE_HOURS", "HOURS"))
made, licence = train_script_corpus(Path(corpus), """Trained only on data this project made (espeak-ng speech, procedural motion): no motion or audio of
SHOW, BEAT2, the audio2photoreal data or any other third-party corpus, so none of their
non-commercial terms apply. The weights are under the licence of convodrive itself.""", stages)
card = f"""
## How these weights were made

- command: `{env}scripts/train_probtalk.sh {Path(corpus).name} {runs.name}` at commit `{commit}`
  (stages vq {steps['vq']}, predictor {steps['predictor']}, refiner {steps['refiner']} steps, `small` preset, seed 0)
- trained on: {where}
- corpus: {made}
- wall time: {"trained before (SHIP_ONLY), " if os.environ.get("SHIP_ONLY") == "1" else f"{(trained - started) / 60:.0f} min to train, "}{(time.time() - started) / 60:.0f} min in all, on
  {os.cpu_count()} CPU cores ({platform.machine()}), load average at the end {os.getloadavg()[0]:.1f}
- shipped: the {chosen} export ({size:.1f} MiB); int8 changes {' and '.join(f'{figure} by {100 * c:+.1f} %' for figure, c in costs.items())}
  on the test split (int8 ships only when that is under {' and '.join(f'{100 * bound:.0f} %' for bound in GATES.values())})

## Test split ({table['conversations']} conversations, {table['samples']} samples each)

| method | {' | '.join(columns)} |
|---|{'---|' * len(columns)}
{chr(10).join(rows)}

## Licence

{licence}
"""
with open(tmp / "MODEL_CARD.md", "a", encoding="utf-8") as f:
    f.write(card)
# MODEL_CARD.md is not among the hashed files of model.json, so appending keeps the folder valid.
shutil.rmtree(model, ignore_errors=True)
tmp.rename(model)
print(f"train_probtalk: wrote {model} ({chosen}, {size:.1f} MiB); card: {model / 'MODEL_CARD.md'}")
EOF
