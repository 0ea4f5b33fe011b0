#!/usr/bin/env bash
# Static checks CI runs beside the tests: ruff (lint and format), mypy on the typed core, and the
# import contracts of docs/ARCHITECTURE.md ("Which part may know which") through import-linter.
#
#   scripts/check.sh          (after scripts/setup.sh --dev)
#
# retargeting/ and backends/ live at the top of the repository but import as convodrive.retargeting
# and convodrive.backends (pyproject's package-dir). mypy and import-linter read packages from the
# file system, so they run on a mirror of the installed layout: real folders, files linked back here.
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
bin=.venv/bin

"$bin/ruff" check --quiet .
"$bin/ruff" format --check --quiet .

layout=$(mktemp -d)
trap 'rm -rf "$layout"' EXIT
"$bin/python" scripts/installed_layout.py "$layout"

# mypy: the canonical motion types, the scheduler, plumbing, plugins, the pipeline, the corpus and
# the simulator side's modules.
(cd "$layout" && "$repo/$bin/mypy" --config-file "$repo/pyproject.toml" \
    convodrive/motion convodrive/scheduler convodrive/plumbing convodrive/plugins convodrive/pipeline \
    convodrive/corpus convodrive/sims)

(cd "$layout" && "$repo/$bin/lint-imports" --config "$repo/.importlinter" --no-cache)
echo "check: ruff, mypy and import contracts pass"
