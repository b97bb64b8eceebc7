"""The studio file: round trip, shipped studios, and rcl's own params-file parser."""

import numpy as np
import pytest

from memo_ros.core.formats.studio import Studio, load_studio
from memo_ros.core.geometry.body import load_default_body
from memo_ros.core.simulation.scenarios import street_camera, studio_cameras


def _same_cameras(a, b):
    assert [c.name for c in a] == [c.name for c in b]
    for x, y in zip(a, b):
        assert (x.width, x.height, x.distortion_model) == (y.width, y.height, y.distortion_model)
        assert np.allclose(x.K, y.K) and np.allclose(x.R_world_cam, y.R_world_cam, atol=1e-9)
        assert np.allclose(x.t_world_cam, y.t_world_cam) and np.allclose(
            x.coefficients, y.coefficients
        )


def test_round_trip_with_node_parameters(tmp_path):
    body = load_default_body()
    studio = Studio(
        's',
        studio_cameras(),
        body,
        30.0,
        {'contour_node': {'threshold': 4.0}},
        {'root_tx': 0.5, 'root_tz': 0.9},
    )
    path = tmp_path / 's.yaml'
    studio.save(path)
    again = Studio.load(path)
    _same_cameras(studio.cameras, again.cameras)
    assert np.allclose(again.body.lengths, body.lengths)
    assert again.node_parameters == {'contour_node': {'threshold': 4.0}}
    assert again.initial_pose == {'root_tx': 0.5, 'root_tz': 0.9}
    assert again.frame_rate == 30.0


def test_shipped_studios_match_the_simulator_rigs():
    _same_cameras(load_studio('studio_orthogonal').cameras, studio_cameras())
    _same_cameras(load_studio('street').cameras, street_camera())
    street = load_studio('street')
    assert street.frame_rate == 25.0
    cam = street.cameras[0]
    # Rohr's scene: the camera is about 11 m from the path and looks across it
    assert abs(cam.t_world_cam[1]) == pytest.approx(11.0)
    assert abs(np.asarray(cam.R_world_cam)[:, 2] @ [1.0, 0, 0]) < 1e-9


def test_orthogonal_studio_axes_are_mutually_orthogonal():
    axes = np.array(
        [np.asarray(c.R_world_cam)[:, 2] for c in load_studio('studio_orthogonal').cameras]
    )
    assert np.allclose(axes @ axes.T, np.eye(3), atol=1e-9)


def test_errors_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError):
        Studio.load(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('contour_node:\n  ros__parameters: {threshold: 1.0}\n')
    with pytest.raises(ValueError, match='not a memo_ros studio'):
        Studio.load(bad)
    bad.write_text('/**:\n  ros__parameters:\n    studio: {cameras: [cam_a]}\n')
    with pytest.raises(ValueError, match='cam_a'):
        Studio.load(bad)


def test_rcl_accepts_the_studio_as_a_params_file(tmp_path, ros_env):
    rclpy = pytest.importorskip('rclpy')
    from rclpy.node import Node

    studio = load_studio('studio_orthogonal')
    studio.node_parameters = {'contour_node': {'threshold': 4.5}}
    path = tmp_path / 'studio.yaml'
    studio.save(path)
    ctx = rclpy.Context()
    rclpy.init(
        args=['--ros-args', '--params-file', str(path)], context=ctx, domain_id=ros_env.domain_id
    )
    try:
        node = Node(
            'contour_node',
            namespace='/cam_side',
            context=ctx,
            automatically_declare_parameters_from_overrides=True,
            enable_rosout=False,
        )
        try:
            assert node.get_parameter('threshold').value == 4.5
            assert list(node.get_parameter('studio.cameras').value) == [
                'cam_front',
                'cam_side',
                'cam_top',
            ]
            assert list(node.get_parameter('studio.cam_front.K').value)[0] == pytest.approx(650.0)
            assert node.get_parameter('body.torso.length').value == pytest.approx(0.56)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
