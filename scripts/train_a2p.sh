#!/usr/bin/env bash
# Reproduce the a2p weights shipped in convodrive/generators/a2p/model/ from a fresh clone: a
# 2-hour bootstrap corpus, the `a2p` recipe's `small` preset stage by stage, guidance
# distillation, ONNX exports in fp32, int8 and "mixed" (int8 but for the denoisers' step graphs,
# whose error compounds over the sampling steps, and the guide's graphs: an int8 guide cost FD_g
# body 9.08 against 7.97 with it float; the memories, run once a window, stay int8), a comparison of the
# three (distilled and DDIM samplers) with knn and random on the corpus's test split, and the
# chosen folder with its card:
# the smallest export that fits in 30 MB and, over both samplers' takes together, costs under 5 %
# on FGD holistic (one sampler's 2 takes a conversation move FGD by about that much from the draws
# alone: an int8 guide flips a code and the rest of the take goes another way) and under 20 % on
# FD_k body (FGD barely sees jitter: int8 teacher step graphs doubled FD_k body at +1 % FGD).
#
#   scripts/setup.sh --dev && scripts/train_a2p.sh [CORPUS_DIR] [RUN_DIR] [MODEL_DIR]
#
# The face side (lip regressor, face denoiser) and the body side (VQ-VAE, guide transformer, body
# denoiser) share nothing, so they train at once, one process each (one core each on a 2-core
# machine); distillation then trains both students in two DDP processes (one on a GPU). The
# corpus is made unless CORPUS_DIR already holds one; a second run resumes each stage where it
# stopped. SCALE=0.05 runs a twentieth of the steps and warm-ups (a quick check of the whole
# pipeline; the shipped weights' card says which SCALE made them); STEPS_face=N (any stage)
# sets one stage's steps. SHIP_ONLY=1 trains nothing (RUN_DIR's stages are done): it exports,
# compares and ships; TRAIN_ONLY=1 stops after training (train on a GPU machine, ship where the
# corpus's audio is). FGD uses the embedder shipped in convodrive/eval/fgd_model/ (made by
# scripts/train_fgd.sh when missing) or FGD_MODEL=DIR; SAMPLES (default 2) sets the takes per
# test conversation, MAX_CONVERSATIONS=N scores only the first N (default: all).
# REAL_VOICES=1, the default (see scripts/train_corpus.sh), mixes real recorded voices into the corpus
# (CORPUS_DIR default corpus2hrv) and augments every stage that hears audio (scripts/real_voices_recipe.sh);
# the card then lists the voices and their licences. REAL_VOICES=0 trains on espeak-ng alone,
# unaugmented (CORPUS_DIR default corpus2h, the weights shipped before these).
# Uses CUDA when torch sees a GPU (--device auto). Logs: RUN_DIR/{face,body,distill}.log.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/real_voices_recipe.sh  # REAL_VOICES, default_corpus, augment
corpus=${1:-$default_corpus}
runs=${2:-runs/a2p-small}
model=${3:-convodrive/generators/a2p/model}
bin=$(pwd)/.venv/bin
scale=${SCALE:-1}
samples=${SAMPLES:-2}
conversations=${MAX_CONVERSATIONS:+--max-conversations $MAX_CONVERSATIONS}
started=$(date +%s)
mkdir -p "$runs"

steps() { "$bin/python" -c "print(max(4, round($1 * $scale)))"; }
stage_steps() { # STAGE FULL: STEPS_<stage> if set, else FULL x SCALE
    local named="STEPS_$1"
    if [ -n "${!named:-}" ]; then echo "${!named}"; else steps "$2"; fi
}

train() { # STAGE STEPS [ARGS...]: one stage, its learning rate decaying over its steps
    local stage=$1 n heard=("${augment[@]}")
    n=$(stage_steps "$stage" "$2")
    shift 2
    if [ "$stage" = vq ]; then heard=(); fi  # the VQ-VAE hears no audio: nothing to augment
    "$bin/convodrive" train a2p --stage "$stage" --corpus "$corpus" --preset small --seed 0 --no-progress \
        --steps "$n" --set "decay_steps=$n" --set "warmup_steps=$(steps 100)" --set val_every=$((n / 4 + 1)) --out "$runs/$stage" "${heard[@]}" "$@"
}

train_all() { # the face and body sides at once, then both students distilled
    local gpu face body status=0 n distill
    gpu=$("$bin/python" -c "import torch; print(int(torch.cuda.is_available()))")
    echo "train_a2p: corpus $corpus, runs in $runs, steps x $scale, $([ "$gpu" = 1 ] && echo GPU || echo CPU)"
    (train lip 1200 --set lr=1e-3 && train face 3600 --init "$runs/lip") >"$runs/face.log" 2>&1 &
    face=$!
    (train vq 3000 --set lr=1e-3 --set "warmup_steps=$(steps 20)" && train guide 3000 --init "$runs/vq" &&
        train body 3200 --init "$runs/guide") >"$runs/body.log" 2>&1 &
    body=$!
    wait $face || status=$?
    wait $body || status=$?
    if [ "$status" != 0 ]; then
        echo "train_a2p: a stage failed; see $runs/face.log and $runs/body.log" >&2
        exit "$status"
    fi
    n=$(stage_steps distill 900)
    distill=("a2p" --stage distill --corpus "$corpus" --preset small --seed 0 --no-progress --steps "$n"
        --set "decay_steps=$n" --set "warmup_steps=$(steps 20)" --set lr=2e-4 --set val_every=$((n / 4 + 1))
        --out "$runs/distill" --init "$runs/face" --init "$runs/body" "${augment[@]}")
    if [ "$gpu" = 1 ]; then
        "$bin/convodrive" train "${distill[@]}" >"$runs/distill.log" 2>&1
    else
        "$bin/python" -m torch.distributed.run --standalone --nproc_per_node 2 -m convodrive.training "${distill[@]}" >"$runs/distill.log" 2>&1
    fi
}

scripts/train_corpus.sh "$corpus"
[ "${SHIP_ONLY:-0}" = 1 ] || train_all
if [ "${TRAIN_ONLY:-0}" = 1 ]; then echo "train_a2p: trained in $runs (TRAIN_ONLY: nothing exported)"; exit 0; fi
trained=$(date +%s)

rm -rf "$runs/fp32" "$runs/int8" "$runs/mixed"
"$bin/convodrive" export "$runs/distill" --out "$runs/fp32"
"$bin/convodrive" export "$runs/distill" --out "$runs/int8" --int8
"$bin/convodrive" export "$runs/distill" --out "$runs/mixed" --int8 \
    --float face_step,body_step,face_student_step,body_student_step,guide_step,guide_audio,vq_decoder
fgd=${FGD_MODEL:-convodrive/eval/fgd_model}
[ -f "$fgd/model.json" ] || scripts/train_fgd.sh "$corpus"
# Both samplers measure each export's cost: DDIM (the default) runs the teacher graphs, the
# distilled sampler the students.
generators=() options=()
for export in fp32 int8 mixed; do
    suffix=$([ $export = fp32 ] || echo "-$export")
    generators+=("a2p$suffix=a2p" "a2p-distilled$suffix=a2p")
    options+=(-G "a2p$suffix.model=$runs/$export" -G "a2p-distilled$suffix.model=$runs/$export"
        -G "a2p-distilled$suffix.sampler=distilled")
done
"$bin/convodrive" eval compare --corpus "$corpus" --split test --samples "$samples" $conversations --seed 0 --fgd-model "$fgd" \
    --generators "$(IFS=,; echo "${generators[*]}"),knn,random" "${options[@]}" --out "$runs/compare"

# The chosen folder replaces the shipped one whole (written beside it, then renamed), with the
# card's last sections: how it was made, what it scores, what it may be used for.
"$bin/python" - "$runs" "$model" "$corpus" "$started" "$trained" <<'EOF'
import json, os, platform, shutil, subprocess, sys, time
from pathlib import Path

from convodrive.training.model_card import train_script_corpus

runs, model, corpus, started, trained = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], *map(int, sys.argv[4:6])
LIMIT = 30_000_000  # bytes the package ships for a2p (issue 13: at most 30 MB)
GATES = {"FGD holistic": 0.05, "FD_k body": 0.20}  # the most an export may cost against fp32, per figure
METRIC = "FGD holistic"
results = (table := json.loads((runs / "compare" / "compare.json").read_text()))["results"]
SAMPLERS = (("DDIM", "a2p"), ("distilled", "a2p-distilled"))
EXPORTS = ("int8", "mixed", "fp32")  # smallest first
costs = {  # export -> sampler -> relative change of METRIC against fp32
    export: {s: results[f"{label}-{export}"][METRIC] / results[label][METRIC] - 1 for s, label in SAMPLERS}
    for export in EXPORTS[:-1]
}
pooled = {  # export -> figure -> relative change summed over both samplers: what GATES bound
    export: {
        figure: sum(results[f"{label}-{export}"][figure] for _, label in SAMPLERS) / sum(results[label][figure] for _, label in SAMPLERS) - 1
        for figure in GATES
    }
    for export in costs
}
folder_size = lambda p: sum(f.stat().st_size for f in p.iterdir())
sizes = {export: folder_size(runs / export) for export in EXPORTS}
passes = lambda e: e == "fp32" or all(pooled[e][figure] < bound for figure, bound in GATES.items())
fits = [e for e in EXPORTS if sizes[e] <= LIMIT and passes(e)]
described = lambda e: f"{e} {sizes[e] / 1e6:.1f} MB" + "".join(f", {f} {c:+.1%}" for f, c in pooled.get(e, {}).items())
if not fits:
    sys.exit(f"train_a2p: no export both fits in {LIMIT / 1e6:.0f} MB and costs under {GATES} ({'; '.join(map(described, EXPORTS))})")
chosen = fits[0]
size = sizes[chosen]
tmp = model.with_name(model.name + ".partial")
shutil.rmtree(tmp, ignore_errors=True)
shutil.copytree(runs / chosen, tmp)
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
columns = [METRIC, "FD_g body", "FD_g face", "FD_k body", "FD_k face", "Div_sample", "Var body", "Var face", "lip r", "mouth shut"]
cell = lambda v: "—" if v is None else f"{v:.3g}"
rows = [f"| {m} | " + " | ".join(cell(r.get(c)) for c in columns) + " |" for m, r in results.items()]
stages = ("lip", "face", "vq", "guide", "body", "distill")
runs_json = {s: json.loads((runs / s / "run.json").read_text()) for s in stages}
steps = ", ".join(f"{s} {run['train_config']['steps']}" for s, run in runs_json.items())
where = ", ".join(f"{s} {run['device']} (torch {run['torch']})" for s, run in runs_json.items())
env = "".join(f"{k}={v} " for k, v in sorted(os.environ.items()) if k in ("SCALE", "SHIP_ONLY", "SAMPLES", "MAX_CONVERSATIONS", "REAL_VOICES", "VOICE_HOURS", "HOURS") or k.startswith("STEPS_"))
made, licence = train_script_corpus(Path(corpus), """Trained only on data this project made (espeak-ng speech, procedural motion): no motion or audio of
the audio2photoreal data or any other third-party corpus, so none of their non-commercial terms
apply. The weights are under the licence of convodrive itself.""", runs_json)
card = f"""
## How these weights were made

- command: `{env}scripts/train_a2p.sh {Path(corpus).name} {runs.name}` at commit `{commit}`
  (stages {steps} steps, `small` preset, seed 0)
- trained on (stage by stage): {where}
- corpus: {made}
- wall time: {"trained before (SHIP_ONLY), " if os.environ.get("SHIP_ONLY") == "1" else f"{(trained - started) / 60:.0f} min to train, "}{(time.time() - started) / 60:.0f} min in all, on
  {os.cpu_count()} CPU cores ({platform.machine()}), load average at the end {os.getloadavg()[0]:.1f}
- shipped: the {chosen} export, {size / 1e6:.1f} MB ({', '.join(f'{e} {sizes[e] / 1e6:.1f} MB' for e in EXPORTS)});
  int8 quantises every graph's MatMuls (dynamic), mixed all but the four denoiser step graphs and the teachers' memories. Against
  fp32, on the test split, {METRIC} changes by {'; '.join(f"{e}: {100 * pooled[e][METRIC]:+.1f} % (" + ', '.join(f'{100 * c:+.1f} % {s}' for s, c in costs[e].items()) + ")" for e in costs)};
  FD_k body by {'; '.join(f"{e}: {100 * pooled[e]['FD_k body']:+.1f} %" for e in costs)};
  the smallest export that fits in {LIMIT / 1e6:.0f} MB and costs {' and '.join(f'under {100 * bound:.0f} % on {figure}' for figure, bound in GATES.items())} over both samplers' takes ships

## Test split ({table['conversations']} conversations, {table['samples']} samples each)

`a2p`: the default, the teacher graphs by DDIM (10 steps for the body, 50 for the face);
`a2p-distilled`: the students; both with the generator's default guidance; no suffix: the fp32
export, `-int8` and `-mixed` the others.

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
print(f"train_a2p: wrote {model} ({chosen}, {size / 1e6:.1f} MB); card: {model / 'MODEL_CARD.md'}")
EOF
