"""`memo-ros benchmark tracker`: camera counts, the cost per added camera, a tiny run.

The report has every figure with sane values (no timing asserted).
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from memo_ros.tools.benchmarks.tracker import (
    parse_cameras,
    per_camera_slope,
    print_tracker_benchmark,
    ring_cameras,
    run_tracker_benchmark,
)


def test_camera_counts_are_parsed_and_refused_with_the_reason():
    assert parse_cameras('3,4,6,8') == (3, 4, 6, 8)
    assert parse_cameras(' 6 ') == (6,)
    for bad in ('', '3,x', '0', '3,65'):
        with pytest.raises(ValueError, match='cameras|camera counts'):
            parse_cameras(bad)


def test_the_cost_per_added_camera_is_the_slope_of_the_medians():
    assert per_camera_slope([3, 4, 6, 8], [7.0, 9.0, 13.0, 17.0]) == pytest.approx(2.0)
    assert per_camera_slope([6, 6], [10.0, 12.0]) is None


def test_ring_cameras_surround_the_studio_and_all_look_at_it():
    cameras = ring_cameras(6)
    centres = np.array([c.centre for c in cameras])
    azimuths = np.sort(np.degrees(np.arctan2(centres[:, 1], centres[:, 0])) % 360)
    assert len({c.name for c in cameras}) == 6
    assert np.allclose(np.diff(azimuths), 60.0)
    assert np.allclose(np.hypot(centres[:, 0], centres[:, 1]), 4.0)
    for camera in cameras:  # the studio's centre, 1 m up, projects into the middle of the image
        u, v = camera.project(np.array([[0.0, 0.0, 1.0]]))[0]
        assert abs(u - camera.width / 2) < 1 and abs(v - camera.height / 2) < 1


def test_a_tiny_run_reports_each_camera_count_and_the_slope(capsys):
    report = run_tracker_benchmark(cameras=(3, 4), frames=3, densities=(200,))
    studio, *ring = report['cases']
    assert (studio['rig'], studio['cameras'], studio['points_per_camera']) == ('studio', 3, 200)
    assert [(c['rig'], c['cameras']) for c in ring] == [('ring', 3), ('ring', 4)]
    for case in report['cases']:
        assert case['frames'] == 2 and case['median_ms'] > 0 and case['cpu_median_ms'] > 0
        assert (
            abs(case['points_actual'] - case['points_per_camera'])
            <= 0.1 * case['points_per_camera']
        )
    assert report['ms_per_camera'] == pytest.approx(ring[1]['median_ms'] - ring[0]['median_ms'])
    print_tracker_benchmark(report)
    assert 'each added camera (1,000 points) costs' in capsys.readouterr().out


def test_tracker_settings_are_named_in_the_report_and_bad_ones_refused(capsys):
    report = run_tracker_benchmark(cameras=(3,), frames=2, densities=())
    print_tracker_benchmark(report | {'tracker': {'hold_sigma_px': 0.0}})
    assert 'TrackerSettings(hold_sigma_px=0.0)' in capsys.readouterr().out
    done = subprocess.run(
        [sys.executable, '-m', 'memo_ros.tools.cli', 'benchmark', 'tracker', '--tracker', 'x=1'],
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and 'not a numeric TrackerSettings' in lines[0]
