#!/usr/bin/env bash
# Reproduce the FGD embedder shipped in convodrive/eval/fgd_model/ from a fresh clone:
# a 2-hour bootstrap corpus, the `fgd` recipe's `small` preset, an ONNX export with its card.
#
#   scripts/setup.sh --dev && scripts/train_fgd.sh [CORPUS_DIR] [RUN_DIR]
#
# The corpus is made unless CORPUS_DIR already holds one. A second run resumes training where it
# stopped. Uses CUDA when torch sees a GPU (--device auto).
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:-corpus2h}
run=${2:-runs/fgd-small}
bin=.venv/bin
scripts/train_corpus.sh "$corpus"
"$bin/convodrive" train fgd --corpus "$corpus" --preset small --seed 0 --out "$run"
"$bin/convodrive" export "$run" --out convodrive/eval/fgd_model
echo "train_fgd: wrote convodrive/eval/fgd_model (see its MODEL_CARD.md)"
