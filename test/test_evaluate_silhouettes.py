"""`memo-ros evaluate --images` without ground truth.

Silhouette IoU per camera, frames lost, overlays.
"""

import json
from pathlib import Path

from conftest import memo_ros_cli
import numpy as np
import pytest

from memo_ros.core.evaluation.silhouette_score import lost_after_start, silhouette_iou
from memo_ros.core.geometry.body import load_studio_actor
from memo_ros.core.geometry.rotations import matrix_to_quat
from memo_ros.ros.bagio import BagWriter, header, pose_array_msg
from memo_ros.tools.evaluate import TRUTH_TOPICS, load_track
from memo_ros.tools.simulate import simulate


@pytest.fixture(scope='module')
def arm(tmp_path_factory):
    """Return a studio-arm bag (10 empty frames, then 8 with the subject) at 320x240.

    And its truth track.
    """
    out = tmp_path_factory.mktemp('arm') / 'rec'
    result = simulate('studio-arm', out, frames=8, width=320, height=240)
    return result, load_track(result.bag, TRUTH_TOPICS)


def write_estimate(path: Path, track, offset=np.zeros(3), outcomes=None) -> Path:
    """Return an estimate bag.

    The truth's poses moved by ``offset`` and each frame's /memo/processed outcome.
    """
    stamps = sorted(track.origins)
    outcomes = outcomes or ['tracking'] * len(stamps)
    with BagWriter(path) as writer:
        for stamp, outcome in zip(stamps, outcomes):
            writer.write('/memo/processed', stamp, header(stamp, outcome))
            if outcome == 'tracking':
                writer.write(
                    '/memo/body_poses',
                    stamp,
                    pose_array_msg(
                        stamp,
                        track.origins[stamp] + offset,
                        matrix_to_quat(track.rotations[stamp]),
                    ),
                )
    return path


def evaluate(estimate: Path, images: Path, *extra) -> dict:
    done = memo_ros_cli(
        'evaluate', '--estimate', estimate, '--images', images, '--json', *extra, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_the_true_poses_cover_the_segmented_person_and_a_shift_does_not(arm, tmp_path):
    result, track = arm
    exact = evaluate(write_estimate(tmp_path / 'exact', track), result.bag)
    shifted = evaluate(
        write_estimate(tmp_path / 'shifted', track, np.array([0.1, 0.1, 0.1])), result.bag
    )
    assert exact['frames'] == 18 and exact['frames_lost_after_start'] == 0
    for camera in result.cameras:
        row = exact['cameras'][camera]
        assert row['frames'] == 8
        # the simulator's picture of the same cylinders, segmented by the studio's background
        # segmenter
        assert row['mean'] > 0.85 and row['min'] > 0.8, (camera, row)
        assert shifted['cameras'][camera]['mean'] < row['mean'] - 0.1, camera
    assert exact['iou_mean_min_camera'] == pytest.approx(
        min(r['mean'] for r in exact['cameras'].values())
    )


def test_frames_lost_after_the_start_are_counted_with_their_reasons(arm, tmp_path):
    result, track = arm
    outcomes = [
        'waiting',
        'tracking',
        'tracking',
        'lost',
        'tracking',
        'no_contours',
        'tracking',
        'tracking',
    ]
    report = evaluate(
        write_estimate(tmp_path / 'gaps', track, outcomes=outcomes),
        result.bag,
        '--per-frame',
        tmp_path / 'iou.csv',
        '--plots',
        tmp_path / 'plots',
    )
    assert report['first_tracked_frame'] == 11  # 10 empty frames, then one waiting
    assert (
        report['frames_lost_after_start'] == 2 + 0
    )  # 'lost' and 'no_contours' (the empty frames came before)
    assert report['lost_reasons'] == {'lost': 1, 'no_contours': 1}
    rows = (tmp_path / 'iou.csv').read_text().splitlines()
    assert rows[0].startswith('frame,stamp_ns,outcome,iou_') and len(rows) == 19
    plots = [Path(p) for p in report['plots']]
    assert (tmp_path / 'plots' / 'iou.png') in plots and all(p.stat().st_size > 0 for p in plots)
    assert any(p.name.startswith('overlay_cam') for p in plots)


def test_evaluate_needs_truth_or_images(tmp_path):
    done = memo_ros_cli('evaluate', '--estimate', tmp_path / 'none', timeout=300)
    assert done.returncode != 0 and 'Traceback' not in done.stderr
    assert '--images' in done.stderr


def test_lost_after_start_and_iou_helpers():
    lost = lost_after_start([None, 'waiting', 'tracking', None, 'lost', 'tracking', 'skipped'])
    assert (lost.first_tracked, lost.after_start, lost.lost) == (2, 4, 3)
    assert lost.reasons == {'lost': 1, 'skipped': 1, 'unreported': 1}
    assert lost_after_start(['waiting']).first_tracked is None
    a = np.zeros((4, 4), bool)
    a[:2] = True
    b = np.zeros((4, 4), bool)
    b[1:3] = True
    assert silhouette_iou(a, b) == pytest.approx(4 / 12)
    assert np.isnan(silhouette_iou(np.zeros((2, 2), bool), np.zeros((2, 2), bool)))


def test_markers_give_back_the_body_the_tracker_used(tmp_path):
    from memo_ros.core.vision.tracked_region import body_region, tracked_person
    from memo_ros.ros.bagio import BagError, tracked_bodies
    from memo_ros.ros.body_messages import (
        MARKERS_TOPIC,
        marker_array_message,
        tracked_body_from_markers,
    )

    body = load_studio_actor()
    q = body.neutral()
    q[0] = 0.3
    rotations, origins = body.forward_kinematics(q)
    stamp = 1_700_000_000_250_000_000
    message = marker_array_message(stamp, body, rotations, origins)
    back_stamp, (back_rotations, back_origins, semi_axes, lengths) = tracked_body_from_markers(
        message
    )
    assert back_stamp == stamp and np.allclose(back_rotations, rotations, atol=1e-9)
    assert np.allclose(back_origins, origins, atol=1e-6)
    assert np.allclose(semi_axes, body.semi_axes) and np.allclose(lengths, body.lengths)
    # a tracker's output bag gives them back by stamp; frames it did not track have no body
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer

    from memo_ros.ros.bagio import TYPESTORE

    writer = Writer(
        tmp_path / 'track', version=9, storage_plugin=StoragePlugin.MCAP
    )  # as replay records it
    writer.open()
    connection = writer.add_connection(
        MARKERS_TOPIC, 'visualization_msgs/msg/MarkerArray', typestore=TYPESTORE
    )
    writer.write(connection, stamp, serialize_message(message))
    writer.close()
    bodies = tracked_bodies(tmp_path / 'track')
    assert list(bodies) == [stamp]
    from memo_ros.core.simulation.scenarios import studio_cameras

    camera = studio_cameras(320, 240)[0]
    person_at = tracked_person(camera, bodies, [stamp - 1, stamp], (240, 320), 4.0)
    assert not person_at(0).any()
    region = person_at(1)
    assert (
        np.array_equal(
            region,
            body_region(camera, rotations, origins, body.semi_axes, body.lengths, (240, 320), 4.0),
        )
        and 0.01 < region.mean() < 0.3
    )
    with BagWriter(tmp_path / 'empty') as writer:
        writer.write('/memo/processed', stamp, header(stamp, 'lost'))
    with pytest.raises(BagError, match='no tracked body'):
        tracked_bodies(tmp_path / 'empty')
