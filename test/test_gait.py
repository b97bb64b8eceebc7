"""Rohr's walking model: periodic, smooth curves driving the whole body from `pose`."""

import numpy as np
import pytest

from memo_ros.core.geometry.body import PART_NAMES, load_studio_actor
from memo_ros.core.walking.gait import ANGLES, GaitCurves, WalkingModel


@pytest.fixture(scope='module')
def curves():
    return GaitCurves()


def test_curves_are_periodic_with_continuous_first_and_second_derivatives(curves):
    for name in ANGLES:
        for d in (0, 1, 2):
            assert curves.angle(name, 0.0, d) == pytest.approx(
                curves.angle(name, 1.0 - 1e-12, d), abs=1e-6
            )
        # across every interior knot the first and second derivatives are continuous
        knots = curves.knots[1:-1]
        for d in (1, 2):
            left = curves.angle(name, knots - 1e-9, d)
            right = curves.angle(name, knots + 1e-9, d)
            assert np.allclose(left, right, atol=1e-4 * (1 + np.abs(left)))


def test_curves_interpolate_the_table(curves):
    table = np.genfromtxt(
        __import__('memo_ros.paths', fromlist=['x']).config_path('gait_cgm23_sagittal.csv'),
        delimiter=',',
        names=True,
    )
    assert np.allclose(
        curves.angle('knee', table['cycle_fraction'][:-1]), np.radians(table['knee_deg'][:-1])
    )


def test_rohr_ten_instants_option():
    ten = GaitCurves(knots=10)
    assert len(ten.knots) == 11
    full = GaitCurves()
    x = np.linspace(0, 1, 200)
    # ten instants keep the knee curve's shape within a few degrees
    assert np.max(np.abs(np.degrees(ten.angle('knee', x) - full.angle('knee', x)))) < 10
    with pytest.raises(ValueError):
        GaitCurves(knots=2)


def test_walking_model_left_lags_right_by_half_a_cycle_and_feet_touch_ground():
    body = load_studio_actor()
    walker = WalkingModel(body)
    pose = np.linspace(0, 1, 50, endpoint=False)
    q = walker.coordinates(pose, x=1.0, y=2.0, heading=0.3)
    hip_l, hip_r = body.coordinate_index('hip_l_y'), body.coordinate_index('hip_r_y')
    q_half = walker.coordinates(np.mod(pose + 0.5, 1.0))
    assert np.allclose(q[:, hip_l], q_half[:, hip_r])
    rotations, origins = body.forward_kinematics(q)
    from memo_ros.core.geometry.body import lowest_point

    assert np.allclose(lowest_point(body, rotations, origins), 0.0, atol=2e-4)
    # the vertical displacement is small and periodic (Rohr §3.2)
    height = walker.pelvis_height(pose)
    assert 0.005 < np.ptp(height) < 0.06
    assert walker.pelvis_height(0.0) == pytest.approx(walker.pelvis_height(1.0))
    assert np.allclose(q[:, 0:2], [1.0, 2.0]) and np.allclose(q[:, 5], 0.3)


def test_heel_strike_posture_at_pose_zero():
    body = load_studio_actor()
    q = WalkingModel(body).coordinates(0.0)
    rotations, origins = body.forward_kinematics(q)
    ends = body.distal_ends(rotations, origins)
    ankle_r = origins[PART_NAMES.index('foot_r')]
    ankle_l = origins[PART_NAMES.index('foot_l')]
    assert ankle_r[0] > ankle_l[0] + 0.3  # right foot ahead at right heel strike
    hand_r = ends[PART_NAMES.index('hand_r')]
    assert hand_r[0] < 0  # right arm swings back
