"""`memo-ros evaluate --keypoints` on the first frames of the real Pose2Sim recording."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from memo_ros.core.evaluation.keypoints import JOINTS, MODEL_PART, SWAP
from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import PART_NAMES
from memo_ros.ros.bagio import BagWriter, pose_array_msg
from memo_ros.tools.keypoint_eval import evaluate_keypoints

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT.parent / 'shared' / 'data' / 'pose2sim_demo_single'
FRAMES = 3

NEEDS_DETECTOR = pytest.mark.skipif(
    importlib.util.find_spec('mediapipe') is None,
    reason='the keypoint detector is not installed (pip install memo_ros[keypoints])',
)
pytestmark = [
    NEEDS_DETECTOR,
    pytest.mark.skipif(
        not (DEMO / 'Calib.qca.txt').is_file(), reason='Pose2Sim demo data not available'
    ),
]


def _cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'memo_ros.tools.cli', *map(str, args)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope='module')
def recording(tmp_path_factory) -> Path:
    """Return the demo's first frames imported at a quarter of their size, as the demo does."""
    out = tmp_path_factory.mktemp('p2s') / 'demo'
    done = _cli(
        'import', 'videos', *[DEMO / f'cam0{i}.mp4' for i in range(1, 5)],
        '--calibration', DEMO / 'Calib.qca.txt', '--out', out, '--scale', '0.25',
        '--encoding', 'bgr8', '--frames', f'0:{FRAMES}',
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return out


def _estimate_bag(path: Path, stamps, joints: np.ndarray) -> None:
    """Write /memo/body_poses whose joint centres are ``joints`` (F, 12, 3)."""
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(PART_NAMES), 1))
    with BagWriter(path) as writer:
        for stamp, frame in zip(stamps, joints):
            origins = np.repeat(frame.mean(0, keepdims=True), len(PART_NAMES), 0)
            for k, joint in enumerate(JOINTS):
                origins[PART_NAMES.index(MODEL_PART[joint])] = frame[k]
            writer.write(
                '/memo/body_poses', int(stamp), pose_array_msg(int(stamp), origins, quats)
            )


def test_the_reference_is_consistent_over_the_cameras_and_faces_forwards(recording, tmp_path):
    studio = Studio.load(recording.with_name('demo.yaml'))
    from memo_ros.tools.keypoints import detect

    detections = detect(recording, studio.camera_names)
    assert detections.uv.shape == (4, FRAMES, 13, 2)
    origins = {int(s): np.zeros((len(PART_NAMES), 3)) for s in detections.stamps}
    report = evaluate_keypoints(recording, origins, studio, tmp_path / 'cache.npz')
    assert np.isfinite(report.reference.points).all()
    assert np.nanmedian(report.reference.error_px) < 8.0, report.reference.error_px
    assert report.nose_in_front == 1.0
    height = report.reference.points[..., 2].max() - report.reference.points[..., 2].min()
    assert 1.0 < height < 1.8  # shoulders to ankles of an adult, metres


def test_the_cli_tells_a_track_on_the_right_sides_from_one_turned_round(recording, tmp_path):
    studio = Studio.load(recording.with_name('demo.yaml'))
    from memo_ros.tools.keypoints import detect

    detections = detect(recording, studio.camera_names)
    origins = {int(s): np.zeros((len(PART_NAMES), 3)) for s in detections.stamps}
    reference = evaluate_keypoints(recording, origins, studio, None).reference.points
    _estimate_bag(tmp_path / 'right', detections.stamps, reference + [0.0, 0.0, 0.02])
    _estimate_bag(tmp_path / 'swapped', detections.stamps, reference[:, SWAP])
    right = _cli('evaluate', '--keypoints', '--images', recording, '--estimate',
                 tmp_path / 'right', '--json')  # fmt: skip
    assert right.returncode == 0, right.stderr
    assert right.stderr == ''  # the detector ran: its native log lines stay off the terminal
    figures = json.loads(right.stdout)
    assert figures['frames_sides_agree'] == FRAMES
    assert figures['mpjpe_raw_mm'] == pytest.approx(20.0, abs=0.5)
    assert figures['mpjpe_offset_removed_mm'] < 0.5
    swapped = _cli('evaluate', '--keypoints', '--images', recording, '--estimate',
                   tmp_path / 'swapped', '--json')  # fmt: skip
    assert swapped.returncode == 0, swapped.stderr
    turned = json.loads(swapped.stdout)
    assert turned['frames_sides_disagree'] == turned['frames_turned'] == FRAMES
    assert figures['frames_legs_swapped'] == figures['frames_arms_swapped'] == 0
    printed = _cli('evaluate', '--keypoints', '--images', recording, '--estimate',
                   tmp_path / 'right', '--plots', tmp_path / 'plots', '--per-frame',
                   tmp_path / 'frames.csv')  # fmt: skip
    assert 'left/right agree' in printed.stdout and printed.returncode == 0
    assert printed.stderr == ''
    assert len((tmp_path / 'frames.csv').read_text().splitlines()) == FRAMES + 1
    assert sorted(p.name for p in (tmp_path / 'plots').iterdir()) == [
        'keypoints_per_frame.png',
        'keypoints_per_joint.png',
    ]


def test_keypoints_need_the_recording(tmp_path):
    done = _cli('evaluate', '--keypoints', '--estimate', tmp_path)
    assert done.returncode == 2 and 'needs --images' in done.stderr
    assert 'Traceback' not in done.stderr
