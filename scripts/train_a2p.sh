#!/usr/bin/env bash
# Reproduce the a2p weights shipped in convodrive/generators/a2p/model/ from a fresh clone: a
# 2-hour bootstrap corpus, the `a2p` recipe's `small` preset stage by stage, consistency
# distillation, an ONNX export with its card.
#
#   scripts/setup.sh --dev && scripts/train_a2p.sh [CORPUS_DIR] [RUN_DIR] [MODEL_DIR]
#
# The face side (lip regressor, face denoiser) and the body side (VQ-VAE, guide transformer, body
# denoiser) share nothing, so they train at once, one process each (one core each on a 2-core
# machine); distillation then trains both students in two DDP processes (one on a GPU). The
# corpus is made unless CORPUS_DIR already holds one; a second run resumes each stage where it
# stopped. SCALE=0.05 runs a twentieth of the steps and warm-ups (a quick check of the whole
# pipeline; the shipped weights' card says which SCALE made them); STEPS_face=N (any stage)
# sets one stage's steps.
# Uses CUDA when torch sees a GPU (--device auto). Logs: RUN_DIR/{face,body,distill}.log.
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:-corpus2h}
runs=${2:-runs/a2p-small}
model=${3:-convodrive/generators/a2p/model}
bin=$(pwd)/.venv/bin
scale=${SCALE:-1}
mkdir -p "$runs"

steps() { "$bin/python" -c "print(max(4, round($1 * $scale)))"; }
stage_steps() { # STAGE FULL: STEPS_<stage> if set, else FULL x SCALE
    local named="STEPS_$1"
    if [ -n "${!named:-}" ]; then echo "${!named}"; else steps "$2"; fi
}

train() { # STAGE STEPS [ARGS...]: one stage, its learning rate decaying over its steps
    local stage=$1 n
    n=$(stage_steps "$stage" "$2")
    shift 2
    "$bin/convodrive" train a2p --stage "$stage" --corpus "$corpus" --preset small --seed 0 --no-progress \
        --steps "$n" --set "decay_steps=$n" --set "warmup_steps=$(steps 100)" --set val_every=$((n / 4 + 1)) --out "$runs/$stage" "$@"
}

[ -f "$corpus/manifest.json" ] || "$bin/convodrive" corpus make --hours 2 --out "$corpus" --seed 0
gpu=$("$bin/python" -c "import torch; print(int(torch.cuda.is_available()))")
echo "train_a2p: corpus $corpus, runs in $runs, steps x $scale, $([ "$gpu" = 1 ] && echo GPU || echo CPU)"

(train lip 1200 --set lr=1e-3 && train face 3600 --init "$runs/lip") >"$runs/face.log" 2>&1 &
face=$!
(train vq 3000 --set lr=1e-3 --set "warmup_steps=$(steps 20)" && train guide 3000 --init "$runs/vq" &&
    train body 3200 --init "$runs/guide") >"$runs/body.log" 2>&1 &
body=$!
status=0
wait $face || status=$?
wait $body || status=$?
if [ "$status" != 0 ]; then
    echo "train_a2p: a stage failed; see $runs/face.log and $runs/body.log" >&2
    exit "$status"
fi

n=$(stage_steps distill 700)
distill=("a2p" --stage distill --corpus "$corpus" --preset small --seed 0 --no-progress --steps "$n"
    --set "decay_steps=$n" --set "warmup_steps=$(steps 20)" --set lr=2e-4 --set val_every=$((n / 4 + 1)) --out "$runs/distill"
    --init "$runs/face" --init "$runs/body")
if [ "$gpu" = 1 ]; then
    "$bin/convodrive" train "${distill[@]}" >"$runs/distill.log" 2>&1
else
    "$bin/python" -m torch.distributed.run --standalone --nproc_per_node 2 -m convodrive.training "${distill[@]}" >"$runs/distill.log" 2>&1
fi
"$bin/convodrive" export "$runs/distill" --out "$model"
echo "train_a2p: wrote $model (see its MODEL_CARD.md)"
