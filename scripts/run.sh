#!/usr/bin/env bash
# The main job on the embedded default: simulate the three-camera studio
# (studio-arm) into out/, then show what was made. Sets up .venv first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
.venv/bin/memo-ros simulate studio-arm --out out/studio-arm --force "$@"
echo
.venv/bin/memo-ros bag info out/studio-arm
