# Sourced by scripts/train_{probtalk,a2p}.sh: with REAL_VOICES=1 (scripts/train_corpus.sh) every
# stage that hears audio is augmented, both channels, bleed included, each kind on a fifth of the
# windows: with half (hardly a window left clean) probtalk's mouth stayed shut on 81-93 % of the
# frames where only the partner speaks with -12 dB bleed; with a fifth, 96-99 %. The model card
# reads what each stage ran with from its run.json, not from here.
augment=()
if [ "${REAL_VOICES:-0}" = 1 ]; then augment=(--set augment=all --set augment_p=0.2); fi
