#!/usr/bin/env bash
# Builds the documentation site into site/ (or serves it: `bash scripts/docs.sh serve`), with
# warnings as errors. Sets up the venv first (scripts/setup_env.sh); extra arguments go to mkdocs.
#   bash scripts/docs.sh            -> site/index.html
#   bash scripts/docs.sh serve      -> http://127.0.0.1:8000/
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${NMRM_VENV:-$ROOT/.venv}"
bash "$ROOT/scripts/setup_env.sh" >/dev/null
cd "$ROOT"
export PATH="$VENV/bin:$PATH"   # mkdocs-typer2 runs `typer` from the venv
export DISABLE_MKDOCS_2_WARNING=true  # we build with the pinned mkdocs 1.6.1
export NO_MKDOCS_2_WARNING=1
if [ "${1:-}" = "serve" ]; then shift; exec python -m mkdocs serve --strict "$@"; fi
exec python -m mkdocs build --strict "$@"
