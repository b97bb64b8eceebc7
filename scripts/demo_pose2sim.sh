#!/usr/bin/env bash
# The real four-camera Pose2Sim demo end to end (README "Real recordings: the Pose2Sim demo"):
# import the videos and their Qualisys calibration (downscaled), set the graph up for a real recording
# (sequence segmenter learning its background from the recording, regions that follow the tracked body,
# body height from the silhouettes), replay the bag through the live graph twice (the second time each
# camera's background is learnt with the body the first pass tracked masked out: the dancer stands in one
# place most of the time, and a plain median learns him into the background), and evaluate without ground
# truth: silhouette IoU per camera, frames lost, overlays. Extra arguments go to `memo-ros import`
# (e.g. --frames 0:40, or --calibration FILE when the folder holds several). Environment:
# POSE2SIM_DEMO (the recording's folder: its videos and calibration, flat or in a Pose2Sim
# project's videos/ and calibration/; default the demo), OUT (output folder), SCALE (0.25).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
DATA=${POSE2SIM_DEMO:-../shared/data/pose2sim_demo_single}
OUT=${OUT:-out/pose2sim}
SCALE=${SCALE:-0.25}
BAG="$OUT/demo"
mkdir -p "$OUT"
rm -rf "$BAG" "$BAG.yaml" "$BAG.pass1" "$BAG.pass1.log" "$BAG.tracked" "$BAG.tracked.log" "$OUT/plots"
start=$(date +%s)

# Four 390 KB colour images per frame overflow Fast DDS's default 512 KB shared-memory segment and
# 208 KB socket buffers: samples then wait for a reliable repair (~2 s) and frames are tracked without a
# camera. A larger segment and buffers (an XML profile, unless one is set already) deliver them at once.
if [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}" ]; then
  cat > "$OUT/fastdds_large_images.xml" <<'XML'
<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>shm_large</transport_id>
      <type>SHM</type>
      <segment_size>16777216</segment_size>
    </transport_descriptor>
    <transport_descriptor>
      <transport_id>udp_large</transport_id>
      <type>UDPv4</type>
      <sendBufferSize>4194304</sendBufferSize>
      <receiveBufferSize>4194304</receiveBufferSize>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="large_images" is_default_profile="true">
    <rtps>
      <userTransports>
        <transport_id>shm_large</transport_id>
        <transport_id>udp_large</transport_id>
      </userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
    </rtps>
  </participant>
</profiles>
XML
  export FASTRTPS_DEFAULT_PROFILES_FILE="$(realpath "$OUT/fastdds_large_images.xml")"
fi

# the folder's videos and its one calibration (flat, or a Pose2Sim project's videos/ and calibration/)
.venv/bin/memo-ros import videos "$DATA" --out "$BAG" --scale "$SCALE" --encoding bgr8 "$@"

# node parameters for a real recording, written into the imported studio file
.venv/bin/python - "$BAG.yaml" "$(realpath "$BAG")" "$SCALE" <<'PY'
import sys
from memo_ros.core.formats.studio import Studio
path, bag, scale = sys.argv[1], sys.argv[2], float(sys.argv[3])
studio = Studio.load(path)
px = scale / 0.25                       # pixel sizes below are for the 0.25 scale (270 x 480 images)
studio.node_parameters['contour_node'] = {
    'segmenter': 'sequence', 'threshold': 12.0, 'background_bag': bag, 'background_frames': 100,
    'keep_regions': 'tracked', 'roi_margin': 6.0 * px, 'learn_margin': max(int(round(3 * px)), 1),
    'min_region_area': int(200 * px * px)}
studio.node_parameters['tracker_node'] = {'body_source': 'silhouettes', 'body_frames': 1}
studio.save(path)
PY

echo "pass 1: background learnt from the recording as it is"
.venv/bin/memo-ros replay "$BAG" --out "$BAG.pass1"
echo
echo "pass 2: background learnt without the body pass 1 tracked"
.venv/bin/python - "$BAG.yaml" "$(realpath "$BAG.pass1")" "$SCALE" <<'PY'
import sys
from memo_ros.core.formats.studio import Studio
path, track, scale = sys.argv[1], sys.argv[2], float(sys.argv[3])
studio = Studio.load(path)
studio.node_parameters['contour_node'].update(background_track=track, background_track_margin=4.0 * scale / 0.25)
studio.save(path)
PY
.venv/bin/memo-ros replay "$BAG" --out "$BAG.tracked"
echo
.venv/bin/memo-ros evaluate --estimate "$BAG.tracked" --images "$BAG" --plots "$OUT/plots" \
    --per-frame "$OUT/iou_per_frame.csv"
echo
echo "done in $(( $(date +%s) - start )) s: overlays in $OUT/plots, the tracker's outputs in $BAG.tracked, node logs in $BAG.tracked.log"
