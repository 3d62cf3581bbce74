#!/usr/bin/env bash
# The test command: set up the venv if needed (scripts/setup_env.sh), then run pytest.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -k messages -x`. The tests run on two
# workers (pytest-xdist; most of a ROS test's time is waiting on other processes):
# NMRM_TEST_WORKERS=N for N, 0 to run them in this process.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# the browser of the labelling page's test: Debian's Chromium (Playwright drives it; it downloads
# no browser of its own); installed with apt where we are root, else that test skips, saying why.
# apt runs beside the venv's set-up (they share nothing) and is waited for before pytest.
CHROMIUM_JOB=""
if ! command -v chromium >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "[test] installing chromium (apt, in the background)"
  (apt-get install -y -q chromium >/dev/null 2>&1 || { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q chromium >/dev/null 2>&1; }) &
  CHROMIUM_JOB=$!
fi
bash "$ROOT/scripts/setup_env.sh"
# the real ROS 2 CLI and launch system (ros2 launch/run/topic/param), used by tests/test_ros2_cli.py;
# those tests skip, saying why, where the kit (outside this repository) is absent
KIT="$ROOT/../shared/tools/ros2-cli-jazzy/install.sh"
if [ -f "$KIT" ]; then bash "$KIT" "${NMRM_VENV:-$ROOT/.venv}"; else echo "[test] no $KIT: real ros2 CLI tests will skip"; fi
# (the browser's install, started above, is waited for here)
if [ -n "${CHROMIUM_JOB:-}" ]; then wait "$CHROMIUM_JOB" || echo "[test] could not install chromium: the browser test will skip"; fi
source "$ROOT/scripts/ros_env.sh"
cd "$ROOT"
# workers, unless the arguments choose (-n) or need one process (--pdb, --trace, -s)
WORKERS=(-n "${NMRM_TEST_WORKERS:-2}")
for arg in "$@"; do
  case "$arg" in -n|-n*|--numprocesses*|--pdb|--trace|-s|--capture=no) WORKERS=() ;; esac
done
exec "$NMRM_VENV/bin/python" -m pytest "${WORKERS[@]}" "$@"
