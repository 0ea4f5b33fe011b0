# Sourced by scripts/train_{probtalk,a2p}.sh once they are in the repository's root: the recipe's
# real voices, one definition for both. REAL_VOICES (default 1; exported, scripts/train_corpus.sh
# reads it) picks the default corpus folder, `default_corpus`: corpus2hrv has the recorded voices
# paired in, corpus2h is espeak-ng alone. With REAL_VOICES=1, every stage that hears audio is
# augmented (`augment`), both channels, bleed included, each kind on a fifth of the windows: with
# half (hardly a window left clean) probtalk's mouth stayed shut on 81-93 % of the frames where only
# the partner speaks with -12 dB bleed; with a fifth, 96-99 %. The model card reads what each stage
# ran with from its run.json, not from here.
export REAL_VOICES=${REAL_VOICES:-1}
default_corpus=$([ "$REAL_VOICES" = 1 ] && echo corpus2hrv || echo corpus2h)
augment=()
if [ "$REAL_VOICES" = 1 ]; then augment=(--set augment=all --set augment_p=0.2); fi
