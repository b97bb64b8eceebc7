#!/usr/bin/env bash
# The main job on the embedded default: simulate the three-camera studio (studio-arm) into out/,
# replay it through the live graph (contour nodes, selector, tracker as processes over DDS),
# and score the tracker against the simulator's truth. Sets up .venv first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
.venv/bin/memo-ros simulate studio-arm --out out/studio-arm --force "$@"
echo
rm -rf out/studio-arm.tracked out/studio-arm.tracked.log out/plots
.venv/bin/memo-ros replay out/studio-arm --out out/studio-arm.tracked
echo
.venv/bin/memo-ros evaluate --truth out/studio-arm --estimate out/studio-arm.tracked --plots out/plots
echo
echo "plots in out/plots, the tracker's outputs in out/studio-arm.tracked, node logs in out/studio-arm.tracked.log"
