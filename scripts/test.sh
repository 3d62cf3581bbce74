#!/usr/bin/env bash
# The test command: set up the venv if needed (scripts/setup_env.sh), then run pytest.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -k messages -x`.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup_env.sh"
source "$ROOT/scripts/ros_env.sh"
cd "$ROOT"
exec "$NMRM_VENV/bin/python" -m pytest "$@"
