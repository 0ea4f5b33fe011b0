#!/usr/bin/env bash
# Retrain the refiner of the shipped ProbTalk weights on their own PQ-VAE decoder and put its graph
# in place; their vq and predictor graphs stay to the bit.
#
#   scripts/setup.sh --dev && scripts/retrain_probtalk_refiner.sh [CORPUS_DIR] [RUN_DIR]
#
# Why: the refiner learns to correct the decoder it runs after, and the vq and predictor stages the
# package ships (made by scripts/train_probtalk.sh; their card says where and how) have no torch
# checkpoints left, while a rerun of those stages on another CPU draws other codes (the model
# card's Still open). So:
#   1. the vq stage with vq_decoder_from: a new encoder fitted to the shipped decoder and codebooks,
#      which stay frozen (2000 steps);
#   2. the predictor stage for one step: the refiner stage inherits a predictor; only the refiner's
#      graph is kept, so this one is never used;
#   3. the refiner stage (3000 steps) with refiner_fd 0.1 (the face's Fréchet distance over each
#      batch), refiner_shut 2.0 (no jaw opened past the truth in self's silence), refiner_shown
#      (the losses read the face's shapes clipped to [0, 1], as the run shows them),
#      refiner_teacher (the body's target, the spine's aside, is the teacher refiner's output, not
#      the truth: the face's terms would otherwise take what the old refiner did for the body),
#      and the spine's Fréchet distance beside the face's, both taken relative to each speaker's
#      mean (refiner_fd_by_speaker; the spine's target is the truth: the codes leave it at its mean);
#   4. `convodrive export --int8 --onto MODEL --graphs refiner` beside the shipped folder (the
#      refiner's motion projection stays float), and the test split scored against the shipped
#      weights.
# The shipped folder is replaced only with SHIP=1, after the figures were read (the model card
# says which must improve); about 30 minutes on 2 idle CPU cores. The corpus is made unless
# CORPUS_DIR holds one (scripts/train_corpus.sh, REAL_VOICES=1 by default: the shipped weights'
# corpus). THREADS: torch's CPU threads (default: the machine's cores). TEACHER: the model folder
# whose refiner teaches the body (default: the shipped folder). The shipped refiner was taught by
# the folder at commit d69c14e (three refiners back); to remake it, take that folder from git first:
#   mkdir -p old && git archive d69c14e convodrive/generators/probtalk/model | tar -x -C old
#   TEACHER=old/convodrive/generators/probtalk/model SHIP=1 scripts/retrain_probtalk_refiner.sh
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/real_voices_recipe.sh  # REAL_VOICES, default_corpus, augment
corpus=${1:-$default_corpus}
runs=${2:-runs/probtalk-refiner}
threads=${THREADS:-$(nproc)}
bin=.venv/bin
model=convodrive/generators/probtalk/model
teacher=${TEACHER:-$model}
scripts/train_corpus.sh "$corpus"

source scripts/probtalk_stage.sh  # train STAGE STEPS [ARGS...]
train vq 2000 --set "vq_decoder_from=$model"
train predictor 1 --set warmup_steps=0 --init "$runs/vq"
train refiner 3000 --init "$runs/predictor" \
    --set refiner_fd=0.1 --set refiner_shut=2.0 --set refiner_shown=true --set "refiner_teacher=$teacher" \
    --set 'refiner_fd_groups=["face","spine"]' --set refiner_fd_by_speaker=true \
    --set 'refiner_teacher_groups=["body_but_spine"]'

rm -rf "$runs/grafted"
"$bin/convodrive" export "$runs/refiner" --int8 --onto "$model" --graphs refiner --out "$runs/grafted"
"$bin/convodrive" eval compare --corpus "$corpus" --split test --stratum synthesised --samples 4 --seed 0 --seeds 4 \
    --generators ground-truth,knn,shipped=probtalk,retrained=probtalk -G "retrained.model=$runs/grafted" \
    --out "$runs/compare"
if [ "${SHIP:-0}" = 1 ]; then
    cp "$model/MODEL_CARD.md" "$runs/grafted/MODEL_CARD.md"
    rm -rf "$model.partial" && cp -r "$runs/grafted" "$model.partial"
    rm -rf "$model" && mv "$model.partial" "$model"
    echo "retrain_probtalk_refiner: the refiner in $model replaced; bring its MODEL_CARD.md up to date"
else
    echo "retrain_probtalk_refiner: $runs/grafted and $runs/compare/compare.md (SHIP=1 puts it in place)"
fi
