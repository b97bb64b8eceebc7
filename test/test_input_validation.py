"""Inputs checked against what they must be, beyond finiteness: intrinsics and contour clouds."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_msgs.msg import PointField

from memo_ros.core.geometry.camera import Camera, intrinsics_problem
from memo_ros.core.vision.contours import CONTOUR_DTYPE
from memo_ros.ros.pointcloud import array_to_pointcloud, contour_cloud_to_table

K = [500.0, 0.0, 319.5, 0.0, 500.0, 239.5, 0.0, 0.0, 1.0]
STUDIO = Camera('cam', 640, 480, np.reshape(K, (3, 3)), np.zeros(5), 'plumb_bob')


@pytest.mark.parametrize(
    ('model', 'd', 'k', 'size', 'words'),
    [
        ('plumb_bob', [np.nan, 0, 0, 0, 0], K, (640, 480), 'not finite'),
        ('plumb_bob', [0.1, 0, 0], K, (640, 480), 'takes 5 distortion coefficients, got 3'),
        ('plumb_bob', [0.0] * 1000, K, (640, 480), 'at most 5'),
        ('equidistant', [0.0] * 4, K, (640, 480), 'unsupported distortion_model'),
        ('fisheye_9000', [0.0] * 4, K, (640, 480), 'unsupported distortion_model'),
        ('plumb_bob', [0.0] * 5, [0.0] * 9, (640, 480), 'not a camera matrix'),
        ('plumb_bob', [0.0] * 5, [-500, 0, 320, 0, 500, 240, 0, 0, 1], (640, 480), 'positive'),
        ('plumb_bob', [0.0] * 5, [500, 0, 5000, 0, 500, 240, 0, 0, 1], (640, 480), 'far from'),
        ('plumb_bob', [0.0] * 5, K, (0, 480), 'image size'),
    ],
)
def test_intrinsics_that_make_no_camera_are_named(model, d, k, size, words):
    problem = intrinsics_problem(*size, model, d, k)
    assert problem is not None and words in problem, problem


def test_intrinsics_that_contradict_the_studio_are_named():
    assert intrinsics_problem(640, 480, 'plumb_bob', [0.0] * 5, K, STUDIO) is None
    assert 'differs from the studio' in intrinsics_problem(
        320, 240, 'plumb_bob', [0.0] * 5, K, STUDIO
    )
    assert 'rational_polynomial differs' in intrinsics_problem(
        640, 480, 'rational_polynomial', [0.1] + [0.0] * 7, K, STUDIO
    )


def _cloud(points: int):
    table = np.zeros(points, CONTOUR_DTYPE)
    table['x'] = np.arange(points)
    return array_to_pointcloud(table)


def test_a_contour_cloud_is_read_when_it_is_one():
    table = contour_cloud_to_table(_cloud(50), max_points=100)
    assert len(table) == 50 and table['x'][49] == 49.0


def test_an_oversized_cloud_is_refused_before_it_is_read():
    msg = _cloud(10)
    msg.width = 2_000_000  # declared, not sent: the size alone refuses it
    with pytest.raises(ValueError, match='more than max_contour_points'):
        contour_cloud_to_table(msg, max_points=50_000)


def test_fields_declared_with_another_type_are_refused_not_reinterpreted():
    msg = _cloud(10)
    for field in msg.fields:
        if field.name in ('x', 'y'):
            field.datatype = PointField.UINT8
    with pytest.raises(ValueError, match=r'field\(s\) x, y not of the contour table'):
        contour_cloud_to_table(msg, max_points=100)
