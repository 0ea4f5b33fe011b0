#!/usr/bin/env bash
# The ProbTalk paper's ablation axes, measured on the corpus's test split (issue 12, item 6):
# 1D against 2D positions and self-only against dyadic training (each a predictor and a refiner
# trained like the shipped model's, from the same PQ-VAE stage), the refiner on (the generator
# leaves it off), the body's low-pass off, T = 1..16 MaskGIT passes, and `live` against `file`
# mode; knn and random as the floor.
#
#   scripts/train_probtalk.sh CORPUS RUNS && scripts/ablate_probtalk.sh [CORPUS] [RUNS]
#
# RUNS is train_probtalk.sh's run folder (its vq stage and fp32 export are reused; the variants can
# train while train_probtalk.sh is still in its refiner stage). Writes
# RUNS/ablation/compare.{md,json,png}. A second run resumes each stage where it stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:-corpus2h}
runs=${2:-runs/probtalk-small}
threads=${THREADS:-1}
samples=${SAMPLES:-4}
bin=.venv/bin
need() { [ -e "$runs/$1" ] || { echo "ablate_probtalk: $runs/$1 is missing: run scripts/train_probtalk.sh first" >&2; exit 2; }; }
need vq/run.json
steps() { .venv/bin/python -c "import json,sys; print(json.load(open(sys.argv[1]))['train_config']['steps'])" "$runs/$1/run.json"; }

# A variant: the shipped model's predictor and refiner steps, one setting changed.
variant() {
    local name=$1 setting=$2 stage from=$runs/vq n
    for stage in predictor refiner; do
        need "$stage/run.json"
        n=$(steps "$stage")
        "$bin/convodrive" train probtalk --corpus "$corpus" --preset small --seed 0 --threads "$threads" \
            --stage "$stage" --steps "$n" --set "decay_steps=$((n - 20))" --set "$setting" \
            --init "$from" --out "$runs/ablation-$name/$stage"
        from=$runs/ablation-$name/$stage
    done
    rm -rf "$runs/ablation-$name/fp32"
    "$bin/convodrive" export "$from" --out "$runs/ablation-$name/fp32"
}
# The two variants train side by side, one thread each (the shipped model's predictor and refiner
# steps are read from its runs, so they must have started).
variant 1d position=1d > "$runs/ablation-1d.log" 2>&1 &
one=$!
variant self-trained dyadic=false > "$runs/ablation-self-trained.log" 2>&1 &
two=$!
wait $one || { echo "ablate_probtalk: the 1d variant failed: $runs/ablation-1d.log" >&2; exit 1; }
wait $two || { echo "ablate_probtalk: the self-trained variant failed: $runs/ablation-self-trained.log" >&2; exit 1; }
need fp32/model.json

fgd=${FGD_MODEL:-convodrive/eval/fgd_model}
model=$runs/fp32
"$bin/convodrive" eval compare --corpus "$corpus" --split test --samples "$samples" --seed 0 --fgd-model "$fgd" \
    --generators probtalk,T1=probtalk,T2=probtalk,T4=probtalk,T16=probtalk,refiner=probtalk,unsmoothed=probtalk,live=probtalk,1d-positions=probtalk,self-trained=probtalk,knn,random \
    -G "probtalk.model=$model" \
    -G "T1.model=$model" -G T1.iterations=1 -G "T2.model=$model" -G T2.iterations=2 \
    -G "T4.model=$model" -G T4.iterations=4 -G "T16.model=$model" -G T16.iterations=16 \
    -G "refiner.model=$model" -G refiner.refine=true \
    -G "unsmoothed.model=$model" -G unsmoothed.smooth=0 -G "live.model=$model" -G live.mode=live \
    -G "1d-positions.model=$runs/ablation-1d/fp32" -G "self-trained.model=$runs/ablation-self-trained/fp32" \
    --out "$runs/ablation"
echo "ablate_probtalk: $runs/ablation/compare.md"
