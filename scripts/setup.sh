#!/usr/bin/env bash
# Create .venv (CPython 3.11, the ROS 2 Jazzy wheels' Python) and install memo_ros
# with its pinned dependencies. Idempotent: reinstalls only when setup.py or
# constraints.txt changed.
set -euo pipefail
cd "$(dirname "$0")/.."
python=${PYTHON:-python3}
if ! "$python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
  echo "memo_ros setup: needs CPython 3.11 (ros-jazzy-rclpy wheels); set PYTHON=/path/to/python3.11" >&2
  exit 1
fi
if [ ! -x .venv/bin/python ]; then
  "$python" -m venv .venv
fi
want=$(cat setup.py setup.cfg constraints.txt | sha256sum | cut -d' ' -f1)
stamp=.venv/.memo_ros_installed
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "memo_ros setup: installing into .venv (first run takes a minute)" >&2
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -c constraints.txt -e '.[test]'
  # memo_ros[keypoints] (evaluate --keypoints) without mediapipe's opencv-contrib-python and jax:
  # the package's opencv-python-headless already provides cv2, and BlazePose needs neither
  .venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps -c constraints.txt \
    mediapipe absl-py attrs flatbuffers protobuf
  echo "$want" > "$stamp"
fi
