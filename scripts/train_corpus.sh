#!/usr/bin/env bash
# The corpus the train scripts share (train_fgd.sh, train_probtalk.sh, train_a2p.sh), made unless
# DIR already holds one: 2 hours of espeak-ng dialogues with procedural motion, seed 0.
#
#   scripts/train_corpus.sh DIR
#
# REAL_VOICES=1 also pairs real recorded voices into dialogues (VOICE_HOURS, default 0.5 h), from
# the Debian packages scripts/real_voices.sh fetches: the CC-BY speakers only (asterisk-it,
# asterisk-ru), never the tests' held-out ones (tests/real_voices.py: HELD_OUT). The train scripts
# then augment both channels (scripts/real_voices_recipe.sh). The manifest and the model card list each
# source with its licence and hours. HOURS (default 2) sets the espeak-ng hours.
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:?usage: scripts/train_corpus.sh DIR}
recorded=(asterisk-it asterisk-ru)  # the CC-BY voices, by their folders' names (the manifest's source names)
if [ -f "$corpus/manifest.json" ]; then  # made before: reused, if it is the corpus asked for
    if [ "${REAL_VOICES:-0}" = 1 ] && ! grep -q "\"${recorded[0]}\"" "$corpus/manifest.json"; then
        echo "train_corpus: $corpus holds a corpus made without REAL_VOICES=1; give another folder" >&2
        exit 1
    fi
    exit 0
fi
voices=()
if [ "${REAL_VOICES:-0}" = 1 ]; then
    cache="${CONVODRIVE_REAL_VOICES:-${XDG_CACHE_HOME:-$HOME/.cache}/convodrive/real_voices}"
    scripts/real_voices.sh "$cache" >/dev/null
    voices=(--voice-hours "${VOICE_HOURS:-0.5}")
    for name in "${recorded[@]}"; do voices+=(--voices "$cache/voices/$name"); done
fi
.venv/bin/convodrive corpus make --hours "${HOURS:-2}" "${voices[@]}" --out "$corpus" --seed 0
