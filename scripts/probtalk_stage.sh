# Sourced by scripts/train_probtalk.sh and scripts/retrain_probtalk_refiner.sh after they set
# corpus, runs, threads, bin and augment (scripts/real_voices_recipe.sh): one way to train a stage.
# `train STAGE STEPS [ARGS...]` runs it into $runs/STAGE, the small preset at seed 0, the learning
# rate decaying over its steps after the preset's 20-step warm-up; every stage that hears audio is
# augmented (the PQ-VAE hears none).
train() {
    local stage=$1 steps=$2 heard=("${augment[@]}")
    shift 2
    if [ "$stage" = vq ]; then heard=(); fi
    "$bin/convodrive" train probtalk --corpus "$corpus" --preset small --seed 0 --threads "$threads" \
        --stage "$stage" --steps "$steps" --set "decay_steps=$((steps > 20 ? steps - 20 : steps))" \
        --out "$runs/$stage" "${heard[@]}" "$@"
}
