"""`memo-ros evaluate` end to end on simulated bags.

Known errors in, the same numbers out (no DDS).
"""

import json
from pathlib import Path

from conftest import memo_ros_cli
import cv2
import numpy as np
import pytest

from memo_ros.core.evaluation.metrics import (
    facing_of_poses,
    heading_error,
    phase_error,
    side_swaps,
)
from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import PART_NAMES, load_studio_actor, other_side
from memo_ros.core.geometry.rotations import matrix_to_quat, rot_x, rot_z
from memo_ros.core.multiview.anatomy import facing
from memo_ros.core.simulation.imaging import ImagingOptions
from memo_ros.ros.bagio import BagWriter, joint_state_msg, pose_array_msg
from memo_ros.tools.evaluate import TRUTH_TOPICS, load_track
from memo_ros.tools.simulate import simulate

# what the `memo-ros` entry point runs (`-m memo_ros.tools.cli` loads cli.py twice, splitting
# CliError)
SUMMARY_KEYS = (
    'frames',
    'mpjpe_mm_mean',
    'mpjpe_mm_max',
    'translation_pct_height_max',
    'axis_deg_max',
    'phase_err_median',
    'phase_err_max',
)
SHIFT_MM = 12.0
TILT_DEG = 2.0


def evaluate_json(truth: Path, estimate: Path, *extra: str) -> dict:
    """Return the --json summary of evaluating ``estimate`` against ``truth``."""
    done = memo_ros_cli('evaluate', '--truth', truth, '--estimate', estimate, '--json', *extra)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def write_estimate(
    path: Path, track, origin_offset=np.zeros(3), local_rotation=np.eye(3), phase=None
) -> Path:
    """Return an estimate bag (/memo/body_poses, /memo/joint_states) from a truth track.

    Every part moved alike.
    """
    with BagWriter(path) as writer:
        for stamp in sorted(track.origins):
            rotations = track.rotations[stamp] @ local_rotation
            writer.write(
                '/memo/body_poses',
                stamp,
                pose_array_msg(
                    stamp, track.origins[stamp] + origin_offset, matrix_to_quat(rotations)
                ),
            )
            joints = dict(track.joints[stamp])
            if phase is not None:
                joints['gait_phase'] = phase(joints['gait_phase'])
            writer.write(
                '/memo/joint_states',
                stamp,
                joint_state_msg(stamp, list(joints), list(joints.values())),
            )
    return path


@pytest.fixture(scope='module')
def arm(tmp_path_factory):
    """Return a 6-frame studio-arm truth bag at 160x120 and its truth track."""
    out = tmp_path_factory.mktemp('arm') / 'truth'
    result = simulate('studio-arm', out, frames=6, width=160, height=120)
    return result, load_track(result.bag, TRUTH_TOPICS)


@pytest.fixture(scope='module')
def walk(tmp_path_factory):
    """Return a 30-frame street-walk truth bag (the gait phase wraps once) and its truth track."""
    out = tmp_path_factory.mktemp('walk') / 'truth'
    result = simulate(
        'street-walk', out, frames=30, width=160, height=120, options=ImagingOptions(noise=0.0)
    )
    return result, load_track(result.bag, TRUTH_TOPICS)


def test_a_bag_against_itself_has_no_error(arm):
    result, _ = arm
    summary = evaluate_json(result.bag, result.bag)
    assert set(SUMMARY_KEYS) <= set(summary)
    assert summary['frames'] == 6 and summary['frames_missing'] == 0
    for key in ('mpjpe_mm_mean', 'mpjpe_mm_max', 'translation_pct_height_max'):
        assert summary[key] == pytest.approx(0.0, abs=1e-9), key
    # arccos of a dot product resolves angles near 0 only to ~sqrt(2 eps) rad ~ 1e-6 deg
    assert summary['axis_deg_max'] == 0.0
    assert summary['phase_err_median'] is None and summary['phase_err_max'] is None


def test_known_shift_and_tilt_are_measured_exactly(arm, tmp_path):
    result, track = arm
    estimate = write_estimate(
        tmp_path / 'estimate',
        track,
        origin_offset=np.array([SHIFT_MM / 1000.0, 0.0, 0.0]),
        local_rotation=rot_x(np.radians(TILT_DEG)),
    )
    summary = evaluate_json(result.bag, estimate)
    height = Studio.load(result.studio).body.standing_height()
    assert summary['frames'] == 6
    assert summary['mpjpe_mm_mean'] == pytest.approx(SHIFT_MM, abs=1e-6)
    assert summary['mpjpe_mm_max'] == pytest.approx(SHIFT_MM, abs=1e-6)
    assert summary['axis_deg_max'] == pytest.approx(TILT_DEG, abs=1e-6)
    assert summary['axis_deg_mean'] == pytest.approx(TILT_DEG, abs=1e-6)
    assert summary['translation_pct_height_max'] == pytest.approx(
        100.0 * SHIFT_MM / 1000.0 / height, abs=1e-9
    )
    assert summary['body_height_m'] == pytest.approx(height)


def test_gait_phase_error_is_taken_modulo_the_cycle(walk, tmp_path):
    result, track = walk
    truth_phase = np.array([track.joints[s]['gait_phase'] for s in sorted(track.joints)])
    assert truth_phase.min() == pytest.approx(0.0) and truth_phase.max() > 0.9  # the truth wraps

    ahead = write_estimate(tmp_path / 'ahead', track, phase=lambda p: (p + 0.03) % 1.0)
    summary = evaluate_json(result.bag, ahead)
    assert summary['phase_err_median'] == pytest.approx(0.03, abs=1e-9)
    assert summary['phase_err_max'] == pytest.approx(0.03, abs=1e-9)
    assert summary['mpjpe_mm_max'] == pytest.approx(0.0, abs=1e-9)

    # where the truth starts a cycle (0.0) the estimate is 0.96 behind it: 0.04, not 0.96
    behind_at_wrap = write_estimate(
        tmp_path / 'wrap', track, phase=lambda p: 0.96 if p < 1e-9 else (p + 0.03) % 1.0
    )
    summary = evaluate_json(result.bag, behind_at_wrap)
    assert summary['phase_err_median'] == pytest.approx(0.03, abs=1e-9)
    assert summary['phase_err_max'] == pytest.approx(0.04, abs=1e-9)
    assert phase_error(np.array([0.99, 0.01]), np.array([0.01, 0.99])) == pytest.approx(
        [0.02, 0.02]
    )


def test_plots_are_written(arm, walk, tmp_path):
    result, track = arm
    estimate = write_estimate(
        tmp_path / 'estimate', track, origin_offset=np.array([0.0, 0.02, 0.0])
    )
    summary = evaluate_json(result.bag, estimate, '--plots', tmp_path / 'plots')
    names = {Path(p).name for p in summary['plots']}
    overlays = sorted(n for n in names if n.startswith('overlay_'))
    assert {'joint_curves.png', 'errors.png'} <= names
    assert len(overlays) == 4 * 3 and {n.split('_')[2] for n in overlays} == {
        'front',
        'side',
        'top',
    }
    for name in names:
        image = cv2.imread(str(tmp_path / 'plots' / name))
        assert image is not None and image.size > 0, name
    overlay = cv2.imread(str(tmp_path / 'plots' / overlays[0]))
    assert overlay.shape == (120, 160, 3)
    assert np.any(overlay[..., 0] != overlay[..., 2])  # the outline is drawn in colour

    walk_result, _ = walk
    summary = evaluate_json(walk_result.bag, walk_result.bag, '--plots', tmp_path / 'walk_plots')
    names = {Path(p).name for p in summary['plots']}
    assert {'joint_curves.png', 'errors.png'} <= names
    assert sum(n.startswith('overlay_cam_street_') for n in names) == 4


def test_bad_input_is_one_line_without_traceback(arm, tmp_path):
    result, _ = arm
    not_a_bag = tmp_path / 'not_a_bag'
    not_a_bag.mkdir()
    (not_a_bag / 'notes.txt').write_text('hello\n')
    for truth, estimate in (
        (tmp_path / 'missing', result.bag),
        (not_a_bag, result.bag),
        (result.bag, tmp_path / 'missing'),
    ):
        done = memo_ros_cli('evaluate', '--truth', truth, '--estimate', estimate)
        assert done.returncode != 0
        assert 'Traceback' not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_heading_error_and_side_swaps_are_found_in_the_frames_they_happen(tmp_path):
    # 1.2 s of studio-dance: frames from 30 on are a second after the first
    result = simulate(
        'studio-dance',
        tmp_path / 'truth',
        frames=36,
        width=80,
        height=60,
        empty_frames=0,
        options=ImagingOptions(noise=0.0),
    )
    track = load_track(result.bag, TRUTH_TOPICS)
    turned = {10: 40.0, 33: -25.0}  # frame -> the estimate's heading error, degrees
    swapped = (5, 34)  # frames with the estimate's left and right parts exchanged
    exchange = [PART_NAMES.index(other_side(p)) for p in PART_NAMES]
    with BagWriter(tmp_path / 'estimate') as writer:
        for k, stamp in enumerate(sorted(track.origins)):
            origins, rotations = track.origins[stamp], track.rotations[stamp]
            turn = rot_z(np.radians(turned.get(k, 0.0)))
            origins = (origins - origins[0]) @ turn.T + origins[0]
            rotations = turn @ rotations
            if k in swapped:
                origins, rotations = origins[exchange], rotations[exchange]
            writer.write(
                '/memo/body_poses',
                stamp,
                pose_array_msg(stamp, origins, matrix_to_quat(rotations)),
            )
    csv = tmp_path / 'frames.csv'
    summary = evaluate_json(result.bag, tmp_path / 'estimate', '--per-frame', csv)
    assert summary['heading_err_deg_max'] == pytest.approx(40.0, abs=1e-6)
    assert summary['heading_err_deg_max_after_1s'] == pytest.approx(25.0, abs=1e-6)
    assert summary['heading_err_deg_mean'] == pytest.approx(65.0 / 36, abs=1e-6)
    assert summary['frames_side_swap'] == 2
    assert summary['frames_side_swap_arms'] == summary['frames_side_swap_legs'] == 2
    rows = [line.split(',') for line in csv.read_text().splitlines()]
    header, rows = rows[0], rows[1:]
    heading = np.array([float(r[header.index('heading_err_deg')]) for r in rows])
    assert np.flatnonzero(np.abs(heading) > 1e-6).tolist() == [10, 33]
    assert heading[33] == pytest.approx(-25.0, abs=1e-6)
    for pair in ('arms', 'legs'):
        flags = [int(r[header.index(f'side_swap_{pair}')]) for r in rows]
        assert np.flatnonzero(flags).tolist() == list(swapped)
    # each part's joint error per frame: nothing off but the turned and the exchanged frames
    hand = np.array([float(r[header.index('joint_mm_hand_l')]) for r in rows])
    torso = np.array([float(r[header.index('joint_mm_torso')]) for r in rows])
    assert np.flatnonzero(hand > 1e-3).tolist() == sorted([10, 33, *swapped])
    assert np.all(torso < 1e-3)  # the root stays where it is when turned about it
    worst = np.array([float(r[header.index('joint_mm_max')]) for r in rows])
    parts = np.array([[float(r[header.index(f'joint_mm_{p}')]) for p in PART_NAMES] for r in rows])
    assert np.allclose(parts.max(axis=1), worst, atol=1e-3)
    plain = evaluate_json(result.bag, result.bag)
    assert plain['heading_err_deg_max'] == 0.0 and plain['frames_side_swap'] == 0


def test_the_heading_of_part_poses_is_anatomy_facing():
    body = load_studio_actor()
    rng = np.random.default_rng(5)
    q = body.neutral() + rng.normal(0.0, 1.0, (20, body.n_coordinates))
    rotations, _ = body.forward_kinematics(q)
    assert np.allclose(facing_of_poses(rotations), facing(body, q), atol=1e-12)
    assert heading_error(rotations, rotations[::-1]) == pytest.approx(
        np.degrees(np.angle(np.exp(1j * (facing(body, q[::-1]) - facing(body, q)))))
    )
    assert side_swaps(np.zeros((3, 14, 3)), np.zeros((3, 14, 3))).shape == (3, 2)
