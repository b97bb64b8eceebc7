"""Camera model and rotation helpers (ROS-free, fast)."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from memo_ros.core.geometry.camera import Camera, perspective_jacobian
from memo_ros.core.geometry.rotations import (
    axis_angle,
    hat,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_to_matrix,
    rot_x,
    rot_y,
    rot_z,
    rotvec_to_matrix,
)

PLUMB_BOB = [-0.28, 0.09, 0.0012, -0.0007, -0.015]
RATIONAL = [0.35, -0.12, 0.0009, -0.0011, 0.02, 0.62, -0.08, 0.03]


def make_camera(model='plumb_bob', skew=0.0, D=None) -> Camera:
    """Return a 640x480 camera about 4 m from the origin looking at it, slightly rolled."""
    if D is None:
        D = {'plumb_bob': PLUMB_BOB, 'rational_polynomial': RATIONAL, 'none': []}[model]
    cam = Camera.look_at(
        'cam',
        eye=(3.2, -2.1, 1.6),
        target=(0.1, 0.2, 0.9),
        width=640,
        height=480,
        fx=520.0,
        fy=515.0,
        cx=318.4,
        cy=243.7,
        D=D,
        distortion_model=model,
    )
    cam.R_world_cam = cam.R_world_cam @ rot_z(0.1)  # roll about the optical axis
    cam.K[0, 1] = skew
    return cam


def points_in_view(cam: Camera, n: int, seed: int = 0, margin: float = 0.8) -> np.ndarray:
    """Random world points in front of the camera.

    Their ideal projections lie within ``margin`` of the image.
    """
    rng = np.random.default_rng(seed)
    depth = rng.uniform(1.0, 6.0, n)
    x = rng.uniform(-margin, margin, n) * (cam.width / 2) / cam.K[0, 0]
    y = rng.uniform(-margin, margin, n) * (cam.height / 2) / cam.K[1, 1]
    return cam.camera_to_world(np.stack([x * depth, y * depth, depth], -1))


def cv2_project(cam: Camera, P: np.ndarray) -> np.ndarray:
    """OpenCV's projection of world points with the camera's pose as rvec/tvec."""
    R_cam_world = cam.R_world_cam.T
    rvec, _ = cv2.Rodrigues(R_cam_world)
    tvec = -R_cam_world @ cam.t_world_cam
    uv, _ = cv2.projectPoints(P.reshape(-1, 1, 3), rvec, tvec, cam.K, cam.coefficients)
    return uv.reshape(-1, 2)


# ---------------------------------------------------------------- projection
@pytest.mark.parametrize('model', ['none', 'plumb_bob', 'rational_polynomial'])
def test_optical_axis_projects_to_principal_point(model):
    cam = make_camera(model)
    axis_points = cam.centre + np.outer([0.5, 2.0, 30.0], cam.R_world_cam[:, 2])
    np.testing.assert_allclose(cam.project(axis_points), np.tile(cam.K[:2, 2], (3, 1)), atol=1e-9)


@pytest.mark.parametrize('model', ['plumb_bob', 'rational_polynomial'])
def test_project_matches_opencv(model):
    cam = make_camera(model)
    P = points_in_view(cam, 500)
    np.testing.assert_allclose(cam.project(P), cv2_project(cam, P), atol=1e-6, rtol=0)


def test_short_plumb_bob_is_zero_padded():
    cam = make_camera('plumb_bob', D=[-0.2, 0.05])
    assert cam.D.tolist() == [-0.2, 0.05, 0.0, 0.0, 0.0]
    P = points_in_view(cam, 50)
    np.testing.assert_allclose(cam.project(P), cv2_project(cam, P), atol=1e-6)


@pytest.mark.parametrize('model', ['', 'none'])
def test_no_distortion_models(model):
    cam = make_camera(model, D=[])
    assert cam.distortion_model == 'none' and not cam.has_distortion
    Pc = np.array([[0.3, -0.2, 2.0]])
    expected = [cam.K[0, 0] * 0.15 + cam.K[0, 2], cam.K[1, 1] * -0.1 + cam.K[1, 2]]
    np.testing.assert_allclose(cam.project_camera(Pc)[0], expected)


def test_bad_distortion_rejected():
    with pytest.raises(ValueError):
        make_camera('equidistant', D=[0.1, 0, 0, 0])
    with pytest.raises(ValueError):
        make_camera('plumb_bob', D=RATIONAL)


def test_points_behind_camera_are_nan():
    cam = make_camera('plumb_bob')
    Pc = np.array([[0.1, 0.2, 2.0], [0.1, 0.2, -1.0], [0.0, 0.0, 0.0]])
    P = cam.camera_to_world(Pc)
    uv = cam.project(P)
    assert np.all(np.isfinite(uv[0])) and np.all(np.isnan(uv[1:]))
    uv2, J = cam.project_with_jacobian(P)
    np.testing.assert_array_equal(np.isnan(uv2), np.isnan(uv))
    assert np.all(np.isfinite(J[0])) and np.all(np.isnan(J[1:]))


def test_project_keeps_leading_dimensions():
    cam = make_camera('rational_polynomial')
    P = points_in_view(cam, 24).reshape(2, 3, 4, 3)
    uv, J = cam.project_with_jacobian(P)
    assert uv.shape == (2, 3, 4, 2) and J.shape == (2, 3, 4, 2, 3)
    np.testing.assert_allclose(uv.reshape(-1, 2), cam.project(P.reshape(-1, 3)))
    assert cam.project(P[0, 0, 0]).shape == (2,)


def test_world_to_camera_inverts_eq5():
    cam = make_camera()
    Pc = np.random.default_rng(1).normal(size=(20, 3))
    np.testing.assert_allclose(cam.world_to_camera(cam.camera_to_world(Pc)), Pc, atol=1e-12)
    np.testing.assert_allclose(cam.world_to_camera(cam.centre), 0.0, atol=1e-12)


# ----------------------------------------------------------------- Jacobians
def numeric_jacobian(f, P: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of f: (N,3) -> (N,2), giving (N,2,3)."""
    J = np.empty(P.shape[:-1] + (2, 3))
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        J[..., k] = (f(P + step) - f(P - step)) / (2 * h)
    return J


@pytest.mark.parametrize('model', ['none', 'plumb_bob', 'rational_polynomial'])
@pytest.mark.parametrize('skew', [0.0, 3.7])
def test_jacobian_matches_finite_differences(model, skew):
    cam = make_camera(model, skew=skew)
    P = points_in_view(cam, 300, seed=2, margin=1.0)
    uv, J = cam.project_with_jacobian(P)
    np.testing.assert_allclose(uv, cam.project(P))
    J_num = numeric_jacobian(cam.project, P)
    scale = np.linalg.norm(J, axis=(-2, -1), keepdims=True)
    assert np.max(np.abs(J - J_num) / scale) < 1e-6


def test_camera_frame_jacobian_is_eq8_without_distortion():
    cam = make_camera('none')
    cam.K[0, 0] = cam.K[1, 1] = 600.0
    Pc = np.array([[0.3, -0.4, 2.5], [-1.0, 0.2, 4.0]])
    H = perspective_jacobian(Pc, f=600.0)
    x, y, z = Pc[0]
    np.testing.assert_allclose(
        H[0], [[600 / z, 0, -x * 600 / z**2], [0, 600 / z, -y * 600 / z**2]]
    )
    np.testing.assert_allclose(cam.projection_jacobian_camera(Pc), H)
    # eq. 9: world Jacobian = H R^-1
    _, J = cam.project_with_jacobian(cam.camera_to_world(Pc))
    np.testing.assert_allclose(J, H @ cam.R_world_cam.T)


def test_camera_frame_jacobian_matches_finite_differences():
    cam = make_camera('rational_polynomial', skew=-2.0)
    Pc = cam.world_to_camera(points_in_view(cam, 100, seed=3))
    J = cam.projection_jacobian_camera(Pc)
    J_num = numeric_jacobian(cam.project_camera, Pc)
    assert np.max(np.abs(J - J_num) / np.linalg.norm(J, axis=(-2, -1), keepdims=True)) < 1e-6


# ---------------------------------------------------------------------- rays
@pytest.mark.parametrize('model', ['none', 'plumb_bob', 'rational_polynomial'])
@pytest.mark.parametrize('skew', [0.0, 2.5])
def test_pixel_rays_reproject_to_their_pixels(model, skew):
    cam = make_camera(model, skew=skew)
    rng = np.random.default_rng(4)
    u = rng.uniform(0, cam.width - 1, 400)
    v = rng.uniform(0, cam.height - 1, 400)
    u[:4] = [0, cam.width - 1, 0, cam.width - 1]  # include the corners
    v[:4] = [0, 0, cam.height - 1, cam.height - 1]
    rays = cam.pixel_rays(u, v)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    for depth in (0.5, 3.0, 20.0):
        uv = cam.project(cam.centre + depth * rays)
        assert np.max(np.hypot(uv[:, 0] - u, uv[:, 1] - v)) < 1e-3
    assert np.all(cam.world_to_camera(cam.centre + rays)[:, 2] > 0)


def test_pixel_rays_match_opencv_without_skew():
    cam = make_camera('rational_polynomial')
    uv = np.array([[10.0, 20.0], [600.0, 400.0], [320.0, 240.0]])
    ideal = cv2.undistortPoints(
        uv[:, None, :],
        cam.K,
        cam.coefficients,
        None,
        np.eye(3),
        np.eye(3),
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15),
    ).reshape(-1, 2)
    d = cam.world_to_camera(cam.centre + cam.pixel_rays(uv[:, 0], uv[:, 1]))
    np.testing.assert_allclose(d[:, :2] / d[:, 2:], ideal, atol=1e-7)


def test_pixel_grid_rays_downscaled_and_cached():
    cam = make_camera('plumb_bob')
    rays = cam.pixel_grid_rays(0.25)
    assert rays.shape == (120, 160, 3)
    assert cam.pixel_grid_rays(0.25) is rays
    assert not rays.flags.writeable
    # pixel centre (u_s, v_s) of the small image is (u_s + 0.5) / s - 0.5 in the full image
    us, vs = 37, 101
    np.testing.assert_allclose(
        rays[vs, us], cam.pixel_rays((us + 0.5) / 0.25 - 0.5, (vs + 0.5) / 0.25 - 0.5), atol=1e-12
    )
    small = cam.scaled(0.25)
    uv = small.project(cam.centre + 2.0 * rays.reshape(-1, 3))
    grid = np.stack(np.meshgrid(np.arange(160.0), np.arange(120.0)), -1).reshape(-1, 2)
    assert np.max(np.abs(uv - grid)) < 1e-3
    full = cam.pixel_grid_rays()
    assert full.shape == (480, 640, 3)
    np.testing.assert_allclose(full[7, 11], cam.pixel_rays(11.0, 7.0), atol=1e-12)
    cam.R_world_cam = cam.R_world_cam @ rot_y(0.2)  # moving the camera invalidates the cache
    assert not np.allclose(cam.pixel_grid_rays(0.25), rays)


@pytest.mark.parametrize('scale', [0.25, 0.5, 2.0])
def test_scaled_camera_half_pixel_convention(scale):
    cam = make_camera('rational_polynomial', skew=1.5)
    small = cam.scaled(scale)
    assert (small.width, small.height) == (round(640 * scale), round(480 * scale))
    np.testing.assert_array_equal(small.D, cam.D)
    P = points_in_view(cam, 100, seed=5)
    np.testing.assert_allclose(small.project(P), (cam.project(P) + 0.5) * scale - 0.5, atol=1e-9)
    assert cam.K[0, 0] == 520.0  # original untouched


def test_scale_must_be_positive():
    with pytest.raises(ValueError):
        make_camera().scaled(0.0)


# ------------------------------------------------------------- construction
def test_look_at_optical_frame():
    cam = Camera.look_at(
        'front', eye=(4.0, 0.0, 1.2), target=(0.0, 0.0, 1.2), width=640, height=480, fx=500.0
    )
    R = cam.R_world_cam
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0)
    np.testing.assert_allclose(R[:, 2], [-1, 0, 0], atol=1e-12)  # looks along -x
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # image y is world down
    np.testing.assert_allclose(R[:, 0], [0, 1, 0], atol=1e-12)  # image x is the camera's right
    np.testing.assert_allclose(cam.project([0.0, 0.0, 1.2]), [319.5, 239.5])
    head, foot = cam.project([[0.0, 0.0, 1.8], [0.0, 0.0, 0.0]])
    assert head[1] < 239.5 < foot[1]  # up in the world is up in the image
    right = cam.project([0.0, 0.5, 1.2])  # +y world is the camera's right here
    assert right[0] > 319.5
    np.testing.assert_allclose(cam.centre, [4.0, 0.0, 1.2])


def test_look_at_oblique_and_degenerate():
    cam = Camera.look_at(
        'c', eye=(2.0, -3.0, 2.5), target=(0.0, 0.0, 1.0), width=320, height=240, fx=300.0
    )
    R = cam.R_world_cam
    assert abs(R[2, 0]) < 1e-12  # optical x stays horizontal (no roll)
    assert R[2, 1] < 0  # optical y has a downward component
    top = Camera.look_at(
        'top', eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), width=320, height=240, fx=300.0
    )
    np.testing.assert_allclose(top.R_world_cam.T @ top.R_world_cam, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(top.R_world_cam[:, 2], [0, 0, -1])
    with pytest.raises(ValueError):
        Camera.look_at('bad', eye=(1, 1, 1), target=(1, 1, 1), width=10, height=10, fx=10.0)


@pytest.mark.parametrize('model', ['none', 'plumb_bob', 'rational_polynomial'])
def test_dict_round_trip(model):
    cam = make_camera(model, skew=0.5)
    data = cam.to_dict()
    assert set(data) == {'name', 'width', 'height', 'distortion_model', 'K', 'D', 'pose'}
    assert len(data['K']) == 9 and len(data['pose']['orientation']) == 4
    assert all(type(v) is float for v in data['K'] + data['D'] + data['pose']['position'])
    back = Camera.from_dict(data)
    assert back.name == cam.name and (back.width, back.height) == (cam.width, cam.height)
    assert back.distortion_model == cam.distortion_model
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.D, cam.D)
    np.testing.assert_allclose(back.R_world_cam, cam.R_world_cam, atol=1e-12)
    np.testing.assert_allclose(back.t_world_cam, cam.t_world_cam)
    # orientation is the optical frame's quaternion in ROS order (x, y, z, w)
    q = Rotation.from_matrix(cam.R_world_cam).as_quat()
    np.testing.assert_allclose(np.abs(data['pose']['orientation']), np.abs(q), atol=1e-12)


def test_dict_yaml_safe():
    yaml = pytest.importorskip('yaml')
    cam = make_camera('rational_polynomial')
    back = Camera.from_dict(yaml.safe_load(yaml.safe_dump(cam.to_dict())))
    np.testing.assert_allclose(
        back.project(points_in_view(cam, 10)), cam.project(points_in_view(cam, 10))
    )


def test_camera_info_fields_round_trip():
    cam = make_camera('rational_polynomial')
    info = cam.to_camera_info_fields()
    assert info['distortion_model'] == 'rational_polynomial' and len(info['d']) == 8
    assert info['r'] == [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    assert info['p'] == [*info['k'][0:3], 0.0, *info['k'][3:6], 0.0, *info['k'][6:9], 0.0]
    assert info['frame_id'] == 'cam_optical_frame'
    back = Camera.from_camera_info_fields(
        **info, R_world_cam=cam.R_world_cam, t_world_cam=cam.t_world_cam
    )
    assert back == cam
    none = Camera.from_camera_info_fields(
        64, 48, '', [], [50.0, 0, 31.5, 0, 50.0, 23.5, 0, 0, 1], frame_id='x'
    )
    assert none.distortion_model == 'none' and none.name == 'x'
    with pytest.raises(ValueError):
        Camera.from_camera_info_fields(64, 48, 'plumb_bob', [], [0.0] * 9, [], [], 'uncalibrated')


# ------------------------------------------------------------------ rotations
def test_rotation_helpers_match_scipy():
    rng = np.random.default_rng(6)
    rv = rng.normal(size=(4, 5, 3))
    R = rotvec_to_matrix(rv)
    assert R.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(
        R.reshape(-1, 3, 3), Rotation.from_rotvec(rv.reshape(-1, 3)).as_matrix(), atol=1e-12
    )
    q = matrix_to_quat(R)
    assert q.shape == (4, 5, 4) and np.all(q[..., 3] >= 0)
    q_ref = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    np.testing.assert_allclose(np.abs(q.reshape(-1, 4)), np.abs(q_ref), atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(-3.0 * q), R, atol=1e-12)  # sign and scale free
    back = matrix_to_rotvec(R)
    np.testing.assert_allclose(rotvec_to_matrix(back), R, atol=1e-12)
    assert np.all(np.linalg.norm(back, axis=-1) <= np.pi + 1e-12)
    for fn, axis in ((rot_x, 'x'), (rot_y, 'y'), (rot_z, 'z')):
        angles = rng.uniform(-np.pi, np.pi, (3, 2))
        np.testing.assert_allclose(
            fn(angles).reshape(-1, 3, 3),
            Rotation.from_euler(axis, angles.reshape(-1, 1)).as_matrix(),
            atol=1e-12,
        )
        assert fn(0.3).shape == (3, 3)
    axes = rng.normal(size=(7, 3))
    ang = rng.uniform(-3, 3, 7)
    unit = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    np.testing.assert_allclose(
        axis_angle(axes, ang), Rotation.from_rotvec(unit * ang[:, None]).as_matrix(), atol=1e-12
    )
    a, b = rng.normal(size=(2, 3))
    np.testing.assert_allclose(hat(a) @ b, np.cross(a, b))


def test_rotvec_stable_near_zero():
    for theta in (0.0, 1e-12, 1e-8, 1e-5, 9.9e-5, 1.01e-4, 1e-3):
        v = np.array([0.6, -0.8, 0.0]) * theta
        np.testing.assert_allclose(
            rotvec_to_matrix(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-15
        )
    np.testing.assert_array_equal(rotvec_to_matrix(np.zeros(3)), np.eye(3))
    # derivative at 0 is the hat operator (finite differences stay well-behaved)
    h = 1e-7
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        np.testing.assert_allclose(
            (rotvec_to_matrix(e) - rotvec_to_matrix(-e)) / (2 * h), hat(np.eye(3)[k]), atol=1e-8
        )


def test_rotations_near_pi_round_trip():
    v = np.array([0.0, 0.0, np.pi - 1e-9])
    np.testing.assert_allclose(
        rotvec_to_matrix(matrix_to_rotvec(rotvec_to_matrix(v))), rotvec_to_matrix(v), atol=1e-9
    )
    R = rot_x(np.pi)
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(R)), R, atol=1e-12)
