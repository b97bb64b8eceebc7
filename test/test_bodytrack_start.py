"""A second real person: the automatic start on PARSEC bodytrack's two frames, judged by anatomy.

Four rolled ceiling cameras, the dataset's own foreground maps as silhouettes, the shipped template
scaled to the measured height, no pose given (as tracker_node's body_source: silhouettes): the
start's left and right must agree with the learned-keypoint reference in both frames.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from test_keypoints_eval import NEEDS_DETECTOR

from memo_ros.core.formats.calibration import _pose_from_extrinsics
from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import load_default_body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.multiview.body_estimation import estimate_body, frame_silhouettes
from memo_ros.core.multiview.tracking import TRACKING, ArticulatedTracker, TrackerSettings
from memo_ros.core.vision.contours import occluding_contours, silhouette_outlines
from memo_ros.ros.bagio import BagWriter, image_msg
from memo_ros.tools.keypoint_eval import evaluate_keypoints

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / 'shared' / 'data' / 'bodytrack_sequenceB_2'
CAMERAS = 4
FRAMES = 2
T0 = 1_800_000_000 * 10**9
DT = 33_333_333

pytestmark = [
    NEEDS_DETECTOR,
    pytest.mark.skipif(
        not (DATA / 'CALIB' / 'Camera1.cal').is_file(), reason='bodytrack data not available'
    ),
]


def _bouguet_camera(path: Path, name: str) -> Camera:
    """Read a Caltech/Bouguet .cal (fc, cc, alpha_c, kc, Rc_ext, Tc_ext in mm, omc_ext)."""
    v = np.loadtxt(path)
    fc, cc, alpha, kc = v[0:2], v[2:4], v[4], v[5:10]
    K = np.array([[fc[0], alpha * fc[0], cc[0]], [0.0, fc[1], cc[1]], [0.0, 0.0, 1.0]])
    pose = _pose_from_extrinsics(v[10:19], v[19:22] / 1000.0)  # X_cam = R X_world + t
    return Camera(name, 640, 480, K, kc, 'plumb_bob', *pose)


def _grey(path: Path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def test_the_start_from_real_foreground_maps_has_left_and_right_of_the_keypoints(tmp_path):
    cams = [
        _bouguet_camera(DATA / 'CALIB' / f'Camera{i}.cal', f'cam{i}')
        for i in range(1, CAMERAS + 1)
    ]
    frames = [
        {
            cam.name: occluding_contours(
                silhouette_outlines(_grey(DATA / f'FG{i}' / f'image000{k}.bmp') > 127)
            )
            for i, cam in enumerate(cams, 1)
        }
        for k in range(FRAMES)
    ]
    body, height = estimate_body([frame_silhouettes(cams, frames[0])], load_default_body())
    assert 1.6 <= height <= 1.9, height  # an adult man
    tracker = ArticulatedTracker(body, cams, TrackerSettings())
    origins = {}
    for k, tables in enumerate(frames):
        result = tracker.step(T0 + k * DT, tables)
        assert result.status == TRACKING, result.reason
        origins[T0 + k * DT] = result.origins
    images = tmp_path / 'images'
    with BagWriter(images) as writer:
        for k in range(FRAMES):
            for i, cam in enumerate(cams, 1):
                grey = _grey(DATA / f'CAM{i}' / f'image000{k}.bmp')
                bgr = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
                msg = image_msg(T0 + k * DT, cam.name, bgr, 'bgr8')
                writer.write(f'/{cam.name}/image_raw', T0 + k * DT, msg)
    summary = evaluate_keypoints(
        images, origins, Studio('bodytrack', cams, body, 30.0), tmp_path / 'cache.npz'
    ).summary()
    print({k: v for k, v in summary.items() if k != 'per_joint'})  # the figures, with pytest -s
    assert summary['frames'] == FRAMES and summary['frames_sides_agree'] == FRAMES, summary
    # 2026-11-27: 79 mm as labelled, 497 mm with the sides exchanged, heading 16 deg off
    assert summary['mpjpe_raw_mm'] <= 120.0, summary
    assert summary['mpjpe_raw_mm'] < 0.5 * summary['mpjpe_sides_swapped_mm'], summary
    assert summary['heading_error_deg_max'] <= 30.0, summary
