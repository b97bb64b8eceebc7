"""Calibration readers and writers.

Round trips, other tools' documented layouts, the real Qualisys file.
"""

from pathlib import Path
import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pytest

from memo_ros.core.formats.calibration import (
    FORMATS,
    CalibrationError,
    detect_format,
    load_calibration,
    read_calibration,
    read_qualisys,
    read_ros,
    read_toml,
    ros_name,
    write_calibration,
)
from memo_ros.core.geometry.camera import Camera

DEMO = Path(__file__).resolve().parent.parent.parent / 'shared' / 'data' / 'pose2sim_demo_single'
QCA = DEMO / 'Calib.qca.txt'
POINTS = np.random.default_rng(1).uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], (300, 3))
PLUMB_BOB = [-0.21, 0.063, 0.0012, -0.0021, 0.011]
RATIONAL = [0.31, -0.12, 0.0008, 0.0013, 0.02, 0.42, -0.05, 0.012]


def rig(rational: bool = True) -> list[Camera]:
    """Cameras with distortion, an off-centre principal point, fx != fy and (in one) skew."""
    a = Camera.look_at(
        'cam_a',
        (3.0, 1.0, 1.5),
        (0.0, 0.0, 1.0),
        width=640,
        height=480,
        fx=600.0,
        fy=612.0,
        cx=322.3,
        cy=241.7,
        D=PLUMB_BOB,
    )
    b = Camera.look_at(
        'cam_b',
        (-2.0, 3.0, 2.2),
        (0.1, 0.0, 0.8),
        width=800,
        height=600,
        fx=700.0,
        D=RATIONAL if rational else PLUMB_BOB,
        distortion_model='rational_polynomial' if rational else 'plumb_bob',
    )
    b.K[0, 1] = 0.7
    c = Camera.look_at(
        'cam_c',
        (0.2, -0.1, 4.0),
        (0.0, 0.0, 0.0),
        up=(1.0, 0.0, 0.0),
        width=320,
        height=240,
        fx=300.0,
    )
    return [a, b, c]


def max_reprojection(expected: list[Camera], got: list[Camera]) -> float:
    """Largest pixel distance between the two rigs' projections of POINTS (visible points only)."""
    worst = 0.0
    for e, g in zip(expected, got, strict=True):
        uv_e, uv_g = e.project(POINTS), g.project(POINTS)
        front = np.all(np.isfinite(uv_e), axis=1)
        assert front.sum() > 100 and np.array_equal(front, np.all(np.isfinite(uv_g), axis=1))
        worst = max(worst, float(np.max(np.linalg.norm(uv_e[front] - uv_g[front], axis=1))))
    return worst


def target(tmp_path: Path, fmt: str) -> Path:
    return tmp_path / {'qualisys': 'Calib.qca.txt', 'toml': 'calibration.toml'}.get(fmt, fmt)


@pytest.mark.parametrize('fmt', FORMATS)
def test_round_trip_reproduces_projections(tmp_path, fmt):
    cameras = rig(rational=fmt in ('toml', 'ros'))
    path = target(tmp_path, fmt)
    write_calibration(cameras, path, fmt)
    assert detect_format(path) == fmt
    calib = load_calibration(path)
    assert calib.fmt == fmt and calib.size_known and not calib.notes
    back = calib.cameras
    assert [c.name for c in back] == [c.name for c in cameras]
    assert [(c.width, c.height) for c in back] == [(c.width, c.height) for c in cameras]
    assert [b.distortion_model if b.has_distortion else None for b in back] == [
        c.distortion_model if c.has_distortion else None for c in cameras
    ]
    assert max_reprojection(cameras, back) < 0.1
    for c, b in zip(cameras, back):
        np.testing.assert_allclose(b.t_world_cam, c.t_world_cam, atol=1e-9)
        np.testing.assert_allclose(b.R_world_cam, c.R_world_cam, atol=1e-9)


@pytest.mark.parametrize('fmt', ['toml', 'easymocap'])
@pytest.mark.parametrize('unit', ['mm', 'cm'])
def test_translation_units(tmp_path, fmt, unit):
    cameras = rig(rational=False)
    path = target(tmp_path, fmt)
    write_calibration(cameras, path, fmt, unit=unit)
    assert max_reprojection(cameras, read_calibration(path, unit=unit)) < 0.1
    in_metres = load_calibration(path)  # read as metres: the rig blows up by 100 or 1000
    scale = {'mm': 1000.0, 'cm': 100.0}[unit]
    np.testing.assert_allclose(
        in_metres.cameras[0].t_world_cam, cameras[0].t_world_cam * scale, rtol=1e-12
    )
    assert in_metres.notes and 'unit' in in_metres.notes[0]


@pytest.mark.parametrize('fmt', ['qualisys', 'easymocap'])
def test_formats_without_rational_model_refuse_it(tmp_path, fmt):
    with pytest.raises(CalibrationError, match='rational_polynomial'):
        write_calibration(rig(rational=True), target(tmp_path, fmt), fmt)


# ---------------------------------------------------------------- the real Qualisys file, read by
# the README's recipe
def pose2sim_reading(path: Path) -> list[dict]:
    """Return the README's recipe, written out independently.

    Size, K, D (k1 k2 p1 p2), world-to-camera rvec, tvec.
    """
    cams = []
    for cam in ET.parse(path).getroot().iter('camera'):
        fov, intr, tr = (
            cam.find('fov_video').attrib,
            cam.find('intrinsic').attrib,
            cam.find('transform').attrib,
        )
        left, top = float(fov['left']), float(fov['top'])
        size = (float(fov['right']) - left + 1, float(fov['bottom']) - top + 1)
        K = np.array(
            [
                [float(intr['focalLengthU']) / 64, 0, float(intr['centerPointU']) / 64 - left],
                [0, float(intr['focalLengthV']) / 64, float(intr['centerPointV']) / 64 - top],
                [0, 0, 1],
            ]
        )
        D = np.array(
            [
                float(intr[k]) / 64
                for k in (
                    'radialDistortion1',
                    'radialDistortion2',
                    'tangentalDistortion1',
                    'tangentalDistortion2',
                )
            ]
        )
        by_column = np.array([float(tr[f'r{i}{j}']) for i in '123' for j in '123']).reshape(3, 3).T
        Rq = by_column  # the camera's rotation (columns read as rows, transposed)
        c = np.array([float(tr[k]) for k in 'xyz']) / 1000.0
        R = Rq.T
        t = -R @ c
        flip = np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1]], float)  # pi about the camera's x axis
        R, t = flip @ R, flip @ t
        cams.append(
            {
                'serial': cam.get('serial'),
                'size': size,
                'K': K,
                'D': D,
                'rvec': cv2.Rodrigues(R)[0],
                'tvec': t,
            }
        )
    return cams


@pytest.mark.skipif(not QCA.is_file(), reason='Pose2Sim demo data not available')
def test_real_qualisys_file_matches_pose2sim_reading():
    cameras = read_qualisys(QCA)
    expected = pose2sim_reading(QCA)
    assert (
        [c.name for c in cameras]
        == ['cam01', 'cam02', 'cam03', 'cam04']
        == [e['serial'] for e in expected]
    )
    # world origin (the treadmill corner), the axes' ends and a patch of floor around it
    floor = np.array([[x, y, 0.0] for x in (-0.5, 0.0, 0.5) for y in (-0.5, 0.0, 0.5)])
    points = np.vstack([np.eye(3) * 0.5, floor])
    for cam, exp in zip(cameras, expected):
        assert (cam.width, cam.height) == exp['size'] == (1088, 1920)
        uv_expected = cv2.projectPoints(points, exp['rvec'], exp['tvec'], exp['K'], exp['D'])[
            0
        ].reshape(-1, 2)
        np.testing.assert_allclose(cam.project(points), uv_expected, atol=1e-6)
        origin = cam.project(np.zeros(3))
        assert (
            0 <= origin[0] < cam.width and 0 <= origin[1] < cam.height
        )  # the corner is in every view
    # the camera centres are the file's x, y, z in millimetres
    np.testing.assert_allclose(
        cameras[0].t_world_cam, [1.4602323709212087, -1.9091590482454608, 1.8965058524092062]
    )


@pytest.mark.skipif(not QCA.is_file(), reason='Pose2Sim demo data not available')
def test_real_qualisys_file_survives_every_format(tmp_path):
    cameras = read_qualisys(QCA)
    for fmt in FORMATS:
        path = target(tmp_path, fmt)
        write_calibration(cameras, path, fmt)
        back = read_calibration(path)
        for c, b in zip(cameras, back):
            uv = c.project(
                np.array(
                    [[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (0, 1)], float
                )
            )
            np.testing.assert_allclose(
                b.project(
                    np.array(
                        [[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (0, 1)], float
                    )
                ),
                uv,
                atol=1e-6,
            )


# ---------------------------------------------------------------- hand-written files in the other
# tools' layouts
# A camera 2 m in front of the world origin, looking along world z, image x along world -y (rotated
# 90 deg about z),
# f = 1000 px, principal point (640, 360), k1 = -0.1.  World point (0.1, 0.2, 0) -> camera (-0.2,
# 0.1, 2)
# -> x, y = (-0.1, 0.05), r2 = 0.0125, radial = 1 - 0.1 r2 = 0.99875 -> u = 640 - 99.875, v = 360 +
# 49.9375.
WORLD_POINT = np.array([0.1, 0.2, 0.0])
EXPECTED_UV = np.array([540.125, 409.9375])
QUARTER_TURN = [0.0, 0.0, float(np.pi / 2)]

POSE2SIM_TOML = f"""
[cam_01]
name = "cam_01"
size = [ 1280.0, 720.0]
matrix = [ [ 1000.0, 0.0, 640.0], [ 0.0, 1000.0, 360.0], [ 0.0, 0.0, 1.0]]
distortions = [ -0.1, 0.0, 0.0, 0.0]
rotation = [ {QUARTER_TURN[0]}, {QUARTER_TURN[1]}, {QUARTER_TURN[2]}]
translation = [ 0.0, 0.0, {{tz}}]
fisheye = {{fisheye}}

[metadata]
adjusted = false
error = 0.0
"""


@pytest.mark.parametrize('tz, unit', [('2.0', 'm'), ('2000.0', 'mm')])
def test_toml_in_pose2sim_and_anipose_layout(tmp_path, tz, unit):
    path = tmp_path / 'Calib_qualisys.toml'
    path.write_text(POSE2SIM_TOML.format(tz=tz, fisheye='false'))
    (cam,) = read_toml(path, unit=unit)
    assert (cam.name, cam.width, cam.height, cam.distortion_model) == (
        'cam_01',
        1280,
        720,
        'plumb_bob',
    )
    np.testing.assert_allclose(cam.project(WORLD_POINT), EXPECTED_UV, atol=1e-9)
    np.testing.assert_allclose(cam.t_world_cam, [0.0, 0.0, -2.0], atol=1e-12)


def test_toml_fisheye_is_refused(tmp_path):
    path = tmp_path / 'calibration.toml'
    path.write_text(POSE2SIM_TOML.format(tz='2.0', fisheye='true'))
    with pytest.raises(CalibrationError, match='fisheye'):
        read_toml(path)


EASYMOCAP_INTRI = """%YAML:1.0
---
names:
   - "01"
K_01: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1000., 0., 640., 0., 1000., 360., 0., 0., 1. ]
dist_01: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.1, 0., 0., 0., 0. ]
"""
EASYMOCAP_EXTRI = f"""%YAML:1.0
---
names:
   - "01"
R_01: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ 0., 0., {QUARTER_TURN[2]!r} ]
Rot_01: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 0., -1., 0., 1., 0., 0., 0., 0., 1. ]
T_01: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ 0., 0., 2. ]
"""


def test_easymocap_layout_without_image_size(tmp_path):
    (tmp_path / 'intri.yml').write_text(EASYMOCAP_INTRI)
    (tmp_path / 'extri.yml').write_text(EASYMOCAP_EXTRI)
    for path in (tmp_path, tmp_path / 'intri.yml', tmp_path / 'extri.yml'):
        calib = load_calibration(path)
        (cam,) = calib.cameras
        assert calib.fmt == 'easymocap' and not calib.size_known and calib.notes
        assert (cam.name, cam.width, cam.height) == (
            'cam01',
            1281,
            721,
        )  # from the principal point
        np.testing.assert_allclose(cam.project(WORLD_POINT), EXPECTED_UV, atol=1e-9)


ROS_CAMERA = """image_width: 1280
image_height: 720
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [1000.0, 0.0, 640.0, 0.0, 1000.0, 360.0, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.1, 0.0, 0.0, 0.0, 0.0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
projection_matrix:
  rows: 3
  cols: 4
  data: [1000.0, 0.0, 640.0, 0.0, 0.0, 1000.0, 360.0, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


def test_ros_camera_calibration_with_poses(tmp_path):
    (tmp_path / 'narrow_stereo.yaml').write_text(ROS_CAMERA)
    # the optical frame of the camera above: R_world_cam = Rz(90deg)^T, centre (0, 0, -2); q of
    # Rz(-90deg)
    s = float(np.sqrt(0.5))
    (tmp_path / 'poses.yaml').write_text(
        f'cameras:\n  narrow_stereo: {{position: [0.0, 0.0, -2.0], orientation: [0.0, 0.0, '
        f'{-s!r}, {s!r}]}}\n'
    )
    for path in (tmp_path, tmp_path / 'poses.yaml', tmp_path / 'narrow_stereo.yaml'):
        assert detect_format(path) == 'ros'
        (cam,) = read_calibration(path)
        assert (cam.name, cam.width, cam.height) == ('narrow_stereo', 1280, 720)
        np.testing.assert_allclose(cam.project(WORLD_POINT), EXPECTED_UV, atol=1e-9)


def test_ros_camera_without_poses_is_refused(tmp_path):
    (tmp_path / 'cam.yaml').write_text(ROS_CAMERA)
    with pytest.raises(CalibrationError, match='no pose'):
        read_ros(tmp_path / 'cam.yaml')


def test_studio_yaml_is_a_calibration(tmp_path):
    from memo_ros.core.formats.studio import Studio
    from memo_ros.core.geometry.body import load_default_body

    cameras = rig()
    Studio('s', cameras, load_default_body()).save(tmp_path / 's.yaml')
    assert detect_format(tmp_path / 's.yaml') == 'studio'
    assert max_reprojection(cameras, read_calibration(tmp_path / 's.yaml')) < 1e-9


def test_unknown_and_broken_files(tmp_path):
    (tmp_path / 'notes.txt').write_text('hello')
    with pytest.raises(CalibrationError, match='unknown calibration format'):
        read_calibration(tmp_path / 'notes.txt')
    with pytest.raises(CalibrationError, match='no calibration'):
        read_calibration(tmp_path / 'missing.toml')
    (tmp_path / 'bad.toml').write_text('[cam_0\nname = ')
    with pytest.raises(CalibrationError, match='not a readable TOML'):
        read_calibration(tmp_path / 'bad.toml')
    (tmp_path / 'x.qca.txt').write_text('<calibration><cameras/></calibration>')
    with pytest.raises(CalibrationError, match='no .*cameras'):
        read_calibration(tmp_path / 'x.qca.txt')
    (tmp_path / 'intri.yml').write_text(EASYMOCAP_INTRI)
    with pytest.raises(CalibrationError, match='extri.yml'):
        read_calibration(tmp_path / 'intri.yml')


def test_camera_names_become_ros_names():
    assert [
        ros_name(n, i) for i, n in enumerate(['cam01', '01', 'Cam 2', '', 'left-eye', '21345'])
    ] == ['cam01', 'cam01', 'Cam_2', 'cam04', 'left_eye', 'cam21345']
