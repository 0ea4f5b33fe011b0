#!/usr/bin/env bash
# Real recorded voices from Debian packages, for tests (and corpora): fetched by package name into
# a cache outside git, laid out as `convodrive corpus make --voices` folders, one per package:
#   CACHE/voices/NAME/source.json   the licence, as read from the package's copyright file
#   CACHE/voices/NAME/SPEAKER/*.wav links to the package's utterances
# and CACHE/voices/INDEX.tsv lists every speaker: folder, utterances, seconds, licence.
# No media is committed; licences are quoted from each package's /usr/share/doc/*/copyright.
#   scripts/real_voices.sh [CACHE]   (default: $CONVODRIVE_REAL_VOICES or ~/.cache/convodrive/real_voices)
set -euo pipefail
cache="${1:-${CONVODRIVE_REAL_VOICES:-${XDG_CACHE_HOME:-$HOME/.cache}/convodrive/real_voices}}"
mkdir -p "$cache/debs" "$cache/root"
cache="$(cd "$cache" && pwd)"

# package | source name | language | speaker: folder inside the package | licence (from its copyright file)
sources=(
  "pocketsphinx-testdata|librivox|en|austen:usr/share/pocketsphinx/test/data/librivox|Public domain (LibriVox recording); package BSD-2 (pocketsphinx-testdata)"
  "asterisk-core-sounds-en-wav|asterisk-en|en|allison:usr/share/asterisk/sounds/en_US_f_Allison|CC-BY-SA-3.0 (Allison Smith, asterisk-core-sounds-en-wav): share-alike"
  "asterisk-core-sounds-fr-wav|asterisk-fr|fr|june:usr/share/asterisk/sounds/fr_CA_f_June|CC-BY-SA-3.0 (June Wallack, asterisk-core-sounds-fr-wav): share-alike"
  "asterisk-core-sounds-it-wav|asterisk-it|it|carlo:usr/share/asterisk/sounds/it_IT_m_Carlo|CC-BY-3.0 (Carlo Flora, asterisk-core-sounds-it-wav)"
  "asterisk-core-sounds-ru-wav|asterisk-ru|ru|maxim:usr/share/asterisk/sounds/ru_RU_f_IvrvoiceRU|CC-BY-3.0 (Maxim Topal, asterisk-core-sounds-ru-wav)"
)

for entry in "${sources[@]}"; do
  IFS='|' read -r pkg name lang where licence <<<"$entry"
  if ! ls "$cache/debs/${pkg}"_*.deb >/dev/null 2>&1; then
    (cd "$cache/debs" && apt-get download -q "$pkg" >/dev/null 2>&1) || {
      echo "real_voices: cannot download $pkg (apt-get download; run apt-get update?)" >&2
      exit 1
    }
  fi
  if [ ! -d "$cache/root/$pkg" ]; then
    dpkg-deb -x "$cache/debs/${pkg}"_*.deb "$cache/root/$pkg.tmp" && mv "$cache/root/$pkg.tmp" "$cache/root/$pkg"
  fi
  speaker="${where%%:*}" inside="${where#*:}"
  dir="$cache/voices/$name"
  mkdir -p "$dir/$speaker"
  for wav in "$cache/root/$pkg/$inside"/*.wav; do ln -sf "$wav" "$dir/$speaker/"; done
  printf '{"name": "%s", "language": "%s", "licence": "%s", "package": "%s"}\n' "$name" "$lang" "$licence" "$pkg" >"$dir/source.json"
done

python3 - "$cache/voices" <<'PY'
import json, sys, wave
from pathlib import Path
root = Path(sys.argv[1])
rows = []
for src in sorted(p for p in root.iterdir() if p.is_dir()):
    licence = json.loads((src / "source.json").read_text())["licence"]
    for spk in sorted(p for p in src.iterdir() if p.is_dir()):
        files = sorted(spk.glob("*.wav"))
        secs = 0.0
        for f in files:
            with wave.open(str(f)) as w:
                secs += w.getnframes() / w.getframerate()
        rows.append(f"{src.name}/{spk.name}\t{len(files)}\t{secs:.1f}\t{licence}")
(root / "INDEX.tsv").write_text("speaker\tutterances\tseconds\tlicence\n" + "\n".join(rows) + "\n")
print("\n".join(rows))
PY
echo "$cache/voices"
