"""`memo-ros benchmark dance`: the runs' figures, the verdict, where a run fails, the options."""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import yaml

from memo_ros.core.geometry.body import PART_NAMES, Body, load_default_body
from memo_ros.core.multiview.body_estimation import scaled_body
from memo_ros.tools.benchmarks.dance import (
    _score,
    print_dance_benchmark,
    run_dance_benchmark,
    tracker_overrides,
)

ROOT = Path(__file__).resolve().parent.parent


def _cli(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'memo_ros.tools.cli', *map(str, args)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_a_short_dance_is_tracked_and_reported(capsys):
    report = run_dance_benchmark(
        [30.0], ['ring4'], frames=6, size=(160, 120), contours='silhouettes', jobs=1
    )
    (run,) = report['runs']
    assert (run['rig'], run['heading_deg'], run['frames'], run['untracked']) == ('ring4', 30, 6, 0)
    assert run['mpjpe_mm_mean'] < 30.0 and run['frames_side_swap'] == 0
    assert run['heading_err_deg_max_after_1s'] is None  # 6 frames end before 1 s
    assert run['passed'] and run['failures'] == []
    assert report['worst']['passed'] == 1 and report['worst']['runs'] == 1
    print_dance_benchmark(report)
    out = capsys.readouterr().out
    assert 'ring4' in out and 'pass' in out and '1 of 1 runs pass' in out
    assert 'exact rendered 160x120 silhouettes' in out


def test_a_dance_started_from_the_silhouettes_is_tracked_without_the_true_pose(capsys):
    report = run_dance_benchmark(
        [30.0], ['ring4'], frames=6, size=(320, 240), contours='silhouettes', start='silhouettes'
    )
    (run,) = report['runs']
    assert report['start'] == 'silhouettes' and run['untracked'] == 0
    assert run['mpjpe_mm_mean'] < 60.0, run  # a standing posture fitted, not the true pose
    given = run_dance_benchmark(
        [30.0], ['ring4'], frames=6, size=(320, 240), contours='silhouettes'
    )['runs'][0]
    assert run['mpjpe_mm_mean'] != given['mpjpe_mm_mean']  # the true pose was not used
    print_dance_benchmark(report)
    assert 'started from the silhouettes (no pose given)' in capsys.readouterr().out


def test_a_dancer_imaged_as_rounded_parts_is_not_the_trackers_shape_and_is_tracked(capsys):
    runs = {
        shape: run_dance_benchmark(
            [30.0], ['ring4'], frames=6, size=(320, 240), contours='silhouettes', shape=shape
        )
        for shape in ('cylinders', 'rounded')
    }
    exact, rounded = (runs[shape]['runs'][0] for shape in ('cylinders', 'rounded'))
    assert rounded['untracked'] == 0 and rounded['frames_side_swap'] == 0
    assert rounded['mpjpe_mm_mean'] < 30.0, rounded
    assert rounded['mpjpe_mm_mean'] != exact['mpjpe_mm_mean']  # other silhouettes, other fit
    print_dance_benchmark(runs['rounded'])
    assert 'imaged as rounded parts' in capsys.readouterr().out


def test_tracker_settings_given_on_the_command_line_reach_the_tracker_and_the_report(capsys):
    report = run_dance_benchmark(
        [30.0],
        ['ring4'],
        frames=3,
        size=(160, 120),
        contours='silhouettes',
        overrides=tracker_overrides(
            ['hold_sigma_px=0', 'hold_hull=false', 'recover_iterations=3']
        ),
    )
    assert report['tracker'] == {'hold_sigma_px': 0.0, 'hold_hull': False, 'recover_iterations': 3}
    print_dance_benchmark(report)
    out = capsys.readouterr().out
    assert 'TrackerSettings(hold_sigma_px=0.0, hold_hull=False, recover_iterations=3)' in out


def test_a_run_fails_where_its_frames_fail_and_says_during_which_moves():
    times = np.arange(120) / 30.0
    joint_mm = np.full((120, len(PART_NAMES)), 10.0)
    hand = PART_NAMES.index('hand_r')
    joint_mm[15:20, hand] = 2000.0  # MPJPE 153 mm at 0.5-0.63 s, the left arm rising
    heading = np.zeros(120)
    heading[10] = 90.0  # before 1 s: not held against the tracker
    heading[80:83] = 25.0  # 2.67-2.73 s, turning
    swaps = np.zeros((120, 2), bool)
    swaps[100, 1] = True  # the legs at 3.33 s
    tracked = np.ones(120, bool)
    tracked[119] = False
    run = _score('ring4', 45.0, times, tracked, joint_mm, heading, swaps, {'limb_exchanges': 3})
    assert not run['passed']
    assert run['mpjpe_mm_max'] == pytest.approx(10.0 + 1990.0 / len(PART_NAMES))
    assert run['heading_err_deg_max_after_1s'] == 25.0
    assert (run['frames_side_swap'], run['frames_side_swap_legs'], run['untracked']) == (1, 1, 1)
    windows = {f['what']: f for f in run['failures']}
    assert set(windows) == {
        'untracked',
        'MPJPE > 100 mm',
        'heading error >= 20 deg',
        'side swap',
    }
    mpjpe = windows['MPJPE > 100 mm']
    assert (mpjpe['start_s'], mpjpe['end_s']) == pytest.approx((0.5, 19 / 30))
    assert 'left arm overhead' in mpjpe['moves'] and next(iter(mpjpe['parts'])) == 'hand_r'
    assert 'turn' in windows['heading error >= 20 deg']['moves']
    assert windows['side swap']['swapped'] == ['legs'] and 'squat' in windows['side swap']['moves']
    fine = _score(
        'ring4', 45.0, times, np.ones(120, bool), np.full((120, 14), 10.0),
        np.zeros(120), np.zeros((120, 2), bool), {'limb_exchanges': 0},
    )  # fmt: skip
    assert fine['passed'] and fine['failures'] == []


def test_a_dancer_of_other_proportions_is_tracked_with_the_measured_average_body(tmp_path, capsys):
    average = load_default_body()
    small = scaled_body(average, 1.60, 'small_160')
    offsets = {joint: offset.copy() for joint, offset in small.joint_offsets.items()}
    for side, sign in (('l', 1.0), ('r', -1.0)):
        offsets[f'shoulder_{side}'][1] = sign * 0.16  # narrower than the scaled 0.174
    narrow = Body(small.shapes, offsets, 'narrow_160')
    path = tmp_path / 'narrow.yaml'
    path.write_text(yaml.safe_dump({'body': narrow.to_dict()}), encoding='utf-8')
    report = run_dance_benchmark(
        [30.0], ['ring4'], frames=4, size=(320, 240), contours='silhouettes',
        body_file=str(path), tracker_body='measured',
    )  # fmt: skip
    (run,) = report['runs']
    assert report['body'] == str(path) and report['tracker_body'] == 'measured'
    assert run['body_height_m'] == pytest.approx(narrow.standing_height())
    assert run['measured_height_m'] == pytest.approx(narrow.standing_height(), abs=0.01)
    assert run['untracked'] == 0 and run['mpjpe_mm_mean'] < 60.0, run
    given = run_dance_benchmark(
        [30.0], ['ring4'], frames=4, size=(320, 240), contours='silhouettes', body_file=str(path)
    )['runs'][0]
    assert given['measured_height_m'] is None
    assert given['mpjpe_mm_mean'] != run['mpjpe_mm_mean']  # the two trackers' bodies differ
    print_dance_benchmark(report)
    out = capsys.readouterr().out
    assert f'dancer: {path} (1.600 m)' in out
    assert "the shipped average scaled to the height measured from the first frame's" in out


@pytest.mark.parametrize(
    ('args', 'words'),
    [
        (('--rig', 'ring5'), "unknown rig 'ring5'; known: orthogonal, ring4, both"),
        (('--headings', 'north'), '--headings must be numbers separated by commas'),
        (('--headings', 'nan'), '--headings must be finite numbers'),
        (('--size', '320'), '--size WxH'),
        (('--contours', 'edges'), "unknown --contours 'edges'"),
        (('--start', 'pose'), "unknown --start 'pose'; known: given, silhouettes"),
        (('--frames', '0'), '--frames must be at least 1'),
        (('--jobs', '0'), '--jobs must be at least 1'),
        (('--tracker', 'nonsense=1'), "--tracker 'nonsense=1': not a numeric TrackerSettings"),
        (('--tracker', 'hold_sigma_px=wide'), "'wide' is not a float"),
        (('--tracker', 'hold_hull=maybe'), "'maybe' is not true or false"),
        (('--tracker', 'recover_margin=-1'), 'must be finite and not negative'),
        (
            ('--tracker-body', 'guessed'),
            "unknown --tracker-body 'guessed'; known: truth, measured",
        ),
        (('--body', 'no/such/body.yaml'), '--body no/such/body.yaml: '),
        (('--shape', 'mesh'), "unknown --shape 'mesh'; known: cylinders, rounded"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(args, words):
    done = _cli('benchmark', 'dance', *args)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and 'Traceback' not in done.stderr, done.stderr
