#!/usr/bin/env bash
# The main job: set up the venv if needed, then run the end-to-end pipeline on a small default
# task (`nmrm demo`). Extra arguments go to `nmrm demo`, e.g. `bash scripts/main.sh --task timer`.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup_env.sh"
source "$ROOT/scripts/ros_env.sh"
cd "$ROOT"
exec "$NMRM_VENV/bin/nmrm" demo "$@"
