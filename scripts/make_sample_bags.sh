#!/usr/bin/env bash
# Regenerates the sample bags in bags/ (screened episodes with oracle labels and ground truth,
# seed 0): 200 Key episodes (used by the main job), 60 of each other navigation task.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/ros_env.sh"
for spec in key:200 timer:60 moving:60 charger:60; do
  task=${spec%%:*}; n=${spec##*:}
  rm -rf "$ROOT/bags/${task}_screened"
  nmrm dataset generate --task "$task" --episodes "$n" --seed 0 --out "$ROOT/bags/${task}_screened"
done
