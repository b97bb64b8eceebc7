"""Camera calibrations of other tools read into and written from :class:`Camera` lists.

Formats (``FORMATS``) and their conventions, all mapped onto memo_ros's
optical frame (z forward, x right, y down) posed in ``world``:

* ``qualisys`` -- QTM's ``.qca.txt`` XML, read as Pose2Sim reads it: image size
  from ``fov_video``; fx, fy, cx, cy, skew and the distortion k1, k2, k3, p1, p2
  in 1/64 units (cx, cy minus the ``fov_video`` left/top); ``r11..r33`` row by
  row form M, whose transpose is the Qualisys camera's orientation (looking
  down its -z) and ``x, y, z`` its centre in millimetres, so world-to-camera is
  ``Rx(pi) M`` and ``R_world_cam = M^T Rx(pi)``.
* ``toml`` -- Anipose / Pose2Sim / FreeMoCap ``calibration.toml``: one table per
  camera with ``name``, ``size = [w, h]``, ``matrix`` (3x3), ``distortions``
  (4, 5 or 8 OpenCV coefficients), ``rotation`` (Rodrigues vector) and
  ``translation`` of the world-to-camera transform, ``fisheye``; ``[metadata]``.
  The translation unit is not stored: metres in Pose2Sim, the calibration
  board's unit (often mm) in Anipose and FreeMoCap -- hence ``unit``.
* ``easymocap`` -- ``intri.yml`` (``names``, ``K_<cam>``, ``dist_<cam>``) and
  ``extri.yml`` (``R_<cam>`` Rodrigues, ``Rot_<cam>``, ``T_<cam>``
  world-to-camera) in OpenCV FileStorage YAML; metres. EasyMocap stores no image
  size: we write ``W_<cam>``/``H_<cam>`` and, without them, estimate it from the
  principal point (``Calibration.size_known`` False).
* ``ros`` -- one ROS ``camera_calibration`` YAML per camera (``<cam>.yaml``) and,
  since those carry no pose, ``poses.yaml``::

      frame_id: world
      cameras:                        # in this order
        cam01: {position: [x, y, z], orientation: [qx, qy, qz, qw]}

  the optical frame of each camera in world (metres), as in the studio YAML.
* ``studio`` (read only) -- a memo_ros studio YAML.

Distortion maps to CameraInfo's ``plumb_bob`` (k1 k2 p1 p2 k3) or
``rational_polynomial`` (8 coefficients); fisheye / equidistant models are
refused, as :class:`Camera` does not implement them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import json
from pathlib import Path
import re
from typing import Literal, overload
import xml.etree.ElementTree as ET

import numpy as np
import tomllib
import yaml

from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.rotations import (
    matrix_to_quat,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_to_matrix,
)

FORMATS = ('qualisys', 'toml', 'easymocap', 'ros')  # readable and writable
READ_FORMATS = FORMATS + ('studio',)
UNITS = {'m': 1.0, 'cm': 0.01, 'mm': 0.001}
QUALISYS_SUBPIXELS = 64  # QTM stores intrinsics in 1/64 pixel (Pose2Sim's reading)
FLIP_X = np.diag(
    [1.0, -1.0, -1.0]
)  # rotation of pi about x: Qualisys camera frame (looks down -z) <-> optical
POSES_FILE = 'poses.yaml'
EASYMOCAP_FILES = ('intri.yml', 'extri.yml')
FAR_CAMERA_M = 100.0  # a camera this far from the origin suggests a unit mix-up


class CalibrationError(ValueError):
    """A calibration file that cannot be read or written as asked."""


@dataclass
class Calibration:
    """Cameras read from a file, the format they came from, and caveats worth telling the user."""

    cameras: list[Camera]
    fmt: str
    size_known: bool = True  # False: image sizes were estimated (the format stores none)
    notes: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------- helpers
def ros_name(raw: str, index: int) -> str:
    """Return a valid ROS name token for a camera.

    Invalid characters to '_', 'cam' prefixed to a leading digit.
    """
    name = re.sub(r'_+', '_', re.sub(r'[^A-Za-z0-9_]', '_', str(raw).strip())).strip('_')
    if not name:
        return f'cam{index + 1:02d}'
    return name if name[0].isalpha() else f'cam{name}'


def natural_key(text: str) -> list:
    """Sort key ordering 'cam2' before 'cam10'."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r'(\d+)', text)]


def _unit_factor(unit: str) -> float:
    if unit not in UNITS:
        raise CalibrationError(f'unknown length unit {unit!r} (use {", ".join(UNITS)})')
    return UNITS[unit]


def distortion_from_coefficients(coeffs, source: str) -> tuple[str, np.ndarray]:
    """(distortion_model, D) of an OpenCV coefficient list (4, 5, 8, or 12/14 with zero extras)."""
    d = np.asarray(coeffs, float).ravel()
    if len(d) in (12, 14):
        if np.any(d[8:]):
            raise CalibrationError(
                f'{source}: thin-prism / tilted distortion terms are not supported'
            )
        d = d[:8]
    if len(d) == 0 or not np.any(d):
        return 'none', np.zeros(0)
    if len(d) in (4, 5):
        return 'plumb_bob', d
    if len(d) == 8:
        return 'rational_polynomial', d
    raise CalibrationError(f'{source}: {len(d)} distortion coefficients (expected 4, 5 or 8)')


def _plumb_bob_only(cam: Camera, fmt: str) -> np.ndarray:
    """k1, k2, p1, p2, k3 of a camera whose format cannot store the rational model's k4..k6."""
    coeffs = cam.coefficients
    if np.any(coeffs[5:]):
        raise CalibrationError(
            f'camera {cam.name!r}: {fmt} cannot store rational_polynomial distortion (k4..k6)'
        )
    return coeffs[:5]


def _pose_from_extrinsics(
    R_cam_world: np.ndarray, t_cam_world: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(R_world_cam, t_world_cam) of a world-to-camera transform Pc = R P + t."""
    R_cam_world = np.asarray(R_cam_world, float).reshape(3, 3)
    return R_cam_world.T, -R_cam_world.T @ np.asarray(t_cam_world, float).reshape(3)


def _extrinsics(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) with Pc = R P + t."""
    R = cam.R_world_cam.T
    return R, -R @ cam.t_world_cam


def _check_names(cameras: list[Camera], source: str) -> None:
    names = [c.name for c in cameras]
    if not cameras:
        raise CalibrationError(f'{source}: no cameras')
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise CalibrationError(f'{source}: duplicate camera names {duplicates}')


def _camera(source: str, **kwargs) -> Camera:
    """Return a Camera, with its validation errors as CalibrationError naming the file."""
    try:
        return Camera(**kwargs)
    except ValueError as exc:
        raise CalibrationError(f'{source}: {exc}') from None


def _far_camera_note(cameras: list[Camera], unit: str, option: str) -> list[str]:
    """Return a note when cameras sit implausibly far from the origin for the unit assumed."""
    far = max(float(np.linalg.norm(c.t_world_cam)) for c in cameras)
    if far > FAR_CAMERA_M:
        return [
            f'a camera is {far:.0f} m from the world origin: is the translation unit really '
            f'{unit!r}? '
            f'(set {option})'
        ]
    return []


def _num(value: float) -> str:
    """Shortest text that reads back as the same float."""
    return repr(float(value))


# ----------------------------------------------------------------------------- Qualisys
def read_qualisys(path: str | Path, video_only: bool = True) -> list[Camera]:
    """Cameras of a Qualisys ``.qca.txt``, read as Pose2Sim does.

    In natural order of their serials.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise CalibrationError(f'{path}: not a readable Qualisys calibration ({exc})') from None
    tags = root.findall('cameras/camera')
    if (
        video_only
    ):  # Pose2Sim keeps the cameras whose model says video (or none); marker cameras film no video
        tags = [t for t in tags if any(m in t.get('model', '').lower() for m in ('video', 'none'))]
    if not tags:
        raise CalibrationError(f'{path}: no (video) cameras in the Qualisys calibration')
    tags.sort(key=lambda t: natural_key(t.get('serial', '')))
    return [_qualisys_camera(tag, i, path) for i, tag in enumerate(tags)]


def _qualisys_number(
    element: ET.Element | None, name: str, key: str, default: str | None = None
) -> float:
    """Attribute ``key`` of a camera's element ``name`` as a number.

    TypeError when the element or the attribute is missing, ValueError when it is no number.
    """
    if element is None:
        raise TypeError(f'no {name}')
    value = element.get(key, default)
    if value is None:
        raise TypeError(f'no {key} in {name}')
    return float(value)


def _qualisys_camera(tag: ET.Element, index: int, path: Path) -> Camera:
    serial = tag.get('serial', '')
    try:
        fov, intr, tr = tag.find('fov_video'), tag.find('intrinsic'), tag.find('transform')

        def edge(key: str) -> float:
            return _qualisys_number(fov, 'fov_video', key)

        left, top = edge('left'), edge('top')
        width = edge('right') - left + 1
        height = edge('bottom') - top + 1

        def sub(key: str, default: str | None = None) -> float:
            return _qualisys_number(intr, 'intrinsic', key, default) / QUALISYS_SUBPIXELS

        K = [
            [sub('focalLengthU'), sub('skew', '0'), sub('centerPointU') - left],
            [0.0, sub('focalLengthV'), sub('centerPointV') - top],
            [0.0, 0.0, 1.0],
        ]
        coefficients = [
            sub('radialDistortion1'),
            sub('radialDistortion2'),
            sub('tangentalDistortion1'),
            sub('tangentalDistortion2'),
            sub('radialDistortion3', '0'),
        ]
        M = np.array(
            [[_qualisys_number(tr, 'transform', f'r{i}{j}') for j in (1, 2, 3)] for i in (1, 2, 3)]
        )
        centre = np.array([_qualisys_number(tr, 'transform', k) for k in 'xyz']) * UNITS['mm']
    except (AttributeError, TypeError, ValueError) as exc:
        raise CalibrationError(
            f'{path}: camera {serial!r}: missing or malformed fov_video, intrinsic or '
            f'transform ({exc})'
        ) from None
    model, D = distortion_from_coefficients(coefficients, f'{path}: camera {serial!r}')
    R_world_cam = M.T @ FLIP_X  # M^T: the Qualisys camera's axes in world; Rx(pi): its -z is our z
    return _camera(
        f'{path}: camera {serial!r}',
        name=ros_name(serial, index),
        width=width,
        height=height,
        K=K,
        D=D,
        distortion_model=model,
        R_world_cam=R_world_cam,
        t_world_cam=centre,
    )


def write_qualisys(cameras: list[Camera], path: str | Path) -> Path:
    """Return a ``.qca.txt`` that :func:`read_qualisys` and Pose2Sim read back as ``cameras``."""
    _check_names(cameras, str(path))
    root = ET.Element(
        'calibration', {'created': 'memo_ros', 'source': 'memo_ros', 'type': 'regular'}
    )
    ET.SubElement(root, 'results', {'min-max-diff': '0.', 'std-dev': '0.'})
    group = ET.SubElement(root, 'cameras')
    for cam in cameras:
        k1, k2, p1, p2, k3 = _plumb_bob_only(cam, 'qualisys') * QUALISYS_SUBPIXELS
        node = ET.SubElement(
            group,
            'camera',
            {
                'active': '1',
                'avg-residual': '0.0',
                'model': 'none',
                'serial': cam.name,
                'viewrotation': '0',
            },
        )
        fov = {'bottom': str(cam.height - 1), 'left': '0', 'right': str(cam.width - 1), 'top': '0'}
        for tag in ('fov_marker', 'fov_marker_max', 'fov_video', 'fov_video_max'):
            ET.SubElement(node, tag, fov)
        M = FLIP_X @ cam.R_world_cam.T
        transform = {f'r{i + 1}{j + 1}': _num(M[i, j]) for i in range(3) for j in range(3)}
        transform.update({k: _num(v / UNITS['mm']) for k, v in zip('xyz', cam.t_world_cam)})
        ET.SubElement(node, 'transform', transform)
        K = cam.K * QUALISYS_SUBPIXELS
        ET.SubElement(
            node,
            'intrinsic',
            {
                'centerPointU': _num(K[0, 2]),
                'centerPointV': _num(K[1, 2]),
                'focalLengthU': _num(K[0, 0]),
                'focalLengthV': _num(K[1, 1]),
                'skew': _num(K[0, 1]),
                'radialDistortion1': _num(k1),
                'radialDistortion2': _num(k2),
                'radialDistortion3': _num(k3),
                'tangentalDistortion1': _num(p1),
                'tangentalDistortion2': _num(p2),
                'sensorMinU': '0',
                'sensorMinV': '0',
                'sensorMaxU': str(cam.width * QUALISYS_SUBPIXELS),
                'sensorMaxV': str(cam.height * QUALISYS_SUBPIXELS),
            },
        )
    ET.indent(root)
    path = Path(path)
    ET.ElementTree(root).write(path, encoding='ASCII', xml_declaration=True)
    return path


# ----------------------------------------------------------------------------- TOML
def read_toml(path: str | Path, unit: str = 'm') -> list[Camera]:
    """Cameras of an Anipose / Pose2Sim / FreeMoCap ``calibration.toml``.

    ``unit`` of its translations.
    """
    path, factor = Path(path), _unit_factor(unit)
    try:
        with open(path, 'rb') as stream:
            data = tomllib.load(stream)
    except (tomllib.TOMLDecodeError, OSError) as exc:
        raise CalibrationError(f'{path}: not a readable TOML calibration ({exc})') from None
    tables = [
        (key, value)
        for key, value in data.items()
        if key != 'metadata' and isinstance(value, dict) and 'matrix' in value
    ]
    if not tables:
        raise CalibrationError(
            f'{path}: no camera tables (with a "matrix") in the TOML calibration'
        )
    cameras = []
    for index, (key, table) in enumerate(tables):
        source = f'{path}: [{key}]'
        if table.get('fisheye', False):
            raise CalibrationError(
                f'{source}: fisheye cameras are not supported (no equidistant model in memo_ros)'
            )
        try:
            width, height = (float(v) for v in table['size'])
            K, rvec = table['matrix'], np.asarray(table['rotation'], float)
            t = np.asarray(table['translation'], float) * factor
            model, D = distortion_from_coefficients(table.get('distortions', []), source)
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(
                f'{source}: missing or malformed size, matrix, rotation or translation ({exc})'
            ) from None
        if (
            rvec.shape != (3,)
            or t.shape != (3,)
            or width != round(width)
            or height != round(height)
        ):
            raise CalibrationError(
                f'{source}: rotation and translation need 3 values and size two integers'
            )
        R_world_cam, t_world_cam = _pose_from_extrinsics(rotvec_to_matrix(rvec), t)
        cameras.append(
            _camera(
                source,
                name=ros_name(table.get('name', key), index),
                width=width,
                height=height,
                K=K,
                D=D,
                distortion_model=model,
                R_world_cam=R_world_cam,
                t_world_cam=t_world_cam,
            )
        )
    return cameras


def write_toml(cameras: list[Camera], path: str | Path, unit: str = 'm') -> Path:
    """Return a ``calibration.toml`` in Anipose's layout (tables cam_0, cam_1, ...).

    Translations in ``unit``.
    """
    factor = _unit_factor(unit)
    _check_names(cameras, str(path))

    def array(values) -> str:
        return '[ ' + ', '.join(_num(v) for v in values) + ']'

    lines = [
        f'# memo_ros calibration: world-to-camera rotation (Rodrigues) and translation in {unit}'
    ]
    for index, cam in enumerate(cameras):
        R, t = _extrinsics(cam)
        lines += [
            f'[cam_{index}]',
            f'name = {json.dumps(cam.name)}',
            f'size = [ {cam.width}, {cam.height}]',
            'matrix = [ ' + ', '.join(array(row) for row in cam.K) + ']',
            f'distortions = {array(cam.D if cam.has_distortion else np.zeros(5))}',
            f'rotation = {array(matrix_to_rotvec(R))}',
            f'translation = {array(t / factor)}',
            'fisheye = false',
            '',
        ]
    lines += ['[metadata]', 'adjusted = false', 'error = 0.0', '']
    path = Path(path)
    path.write_text('\n'.join(lines), encoding='utf-8')
    return path


# ----------------------------------------------------------------------------- EasyMocap
def _easymocap_paths(path: Path) -> tuple[Path, Path]:
    folder = path if path.is_dir() else path.parent
    intri, extri = (folder / name for name in EASYMOCAP_FILES)
    for file in (intri, extri):
        if not file.is_file():
            raise CalibrationError(
                f'EasyMocap calibration needs {EASYMOCAP_FILES[0]} and {EASYMOCAP_FILES[1]} '
                f'together: no {file}'
            )
    return intri, extri


def _open_storage(path: Path):
    import cv2

    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise CalibrationError(
            f'{path}: not an OpenCV FileStorage YAML ({" ".join(str(exc).split())})'
        ) from None
    if not storage.isOpened():
        raise CalibrationError(f'{path}: cannot open as OpenCV FileStorage YAML')
    return storage


def _storage_names(storage, path: Path) -> list[str]:
    node = storage.getNode('names')
    if node.empty() or not node.isSeq():
        raise CalibrationError(f'{path}: no "names" list')
    items = [node.at(i) for i in range(node.size())]
    return [item.string() if item.isString() else str(int(item.real())) for item in items]


@overload
def _storage_matrix(
    storage, key: str, path: Path, required: Literal[True] = True
) -> np.ndarray: ...


@overload
def _storage_matrix(
    storage, key: str, path: Path, required: Literal[False]
) -> np.ndarray | None: ...


def _storage_matrix(storage, key: str, path: Path, required: bool = True) -> np.ndarray | None:
    node = storage.getNode(key)
    if node.empty():
        if required:
            raise CalibrationError(f'{path}: no {key}')
        return None
    value = node.mat() if node.isMap() else np.array([node.real()])
    return np.asarray(value, float)


def read_easymocap(path: str | Path, unit: str = 'm') -> list[Camera]:
    """Cameras of EasyMocap's ``intri.yml`` + ``extri.yml``.

    ``path`` is the folder or either file.
    """
    return _read_easymocap(Path(path), unit)[0]


def _read_easymocap(path: Path, unit: str) -> tuple[list[Camera], bool]:
    factor = _unit_factor(unit)
    intri_path, extri_path = _easymocap_paths(path)
    intri, extri = _open_storage(intri_path), _open_storage(extri_path)
    cameras, size_known = [], True
    for index, raw in enumerate(_storage_names(intri, intri_path)):
        source = f'{intri_path.parent}: camera {raw!r}'
        K = _storage_matrix(intri, f'K_{raw}', intri_path)
        model, D = distortion_from_coefficients(
            _storage_matrix(intri, f'dist_{raw}', intri_path), source
        )
        rvec = _storage_matrix(
            extri, f'R_{raw}', extri_path, required=False
        )  # EasyMocap itself reads R_ first
        R = (
            rotvec_to_matrix(rvec.ravel())
            if rvec is not None
            else _storage_matrix(extri, f'Rot_{raw}', extri_path)
        )
        T = _storage_matrix(extri, f'T_{raw}', extri_path).ravel() * factor
        if K.shape != (3, 3) or R.size != 9 or T.shape != (3,):
            raise CalibrationError(
                f'{source}: K must be 3x3, R a Rodrigues vector or 3x3, T 3 values'
            )
        W, H = (_storage_matrix(intri, f'{k}_{raw}', intri_path, required=False) for k in 'WH')
        if (
            W is None or H is None
        ):  # not stored by EasyMocap: the principal point's pixel taken as the centre
            size_known = False
            W, H = np.array([2 * K[0, 2] + 1]), np.array([2 * K[1, 2] + 1])
        R_world_cam, t_world_cam = _pose_from_extrinsics(R, T)
        cameras.append(
            _camera(
                source,
                name=ros_name(raw, index),
                width=round(float(W[0])),
                height=round(float(H[0])),
                K=K,
                D=D,
                distortion_model=model,
                R_world_cam=R_world_cam,
                t_world_cam=t_world_cam,
            )
        )
    return cameras, size_known


def write_easymocap(cameras: list[Camera], folder: str | Path, unit: str = 'm') -> list[Path]:
    """``intri.yml`` and ``extri.yml`` in ``folder`` (plus W_/H_ image sizes EasyMocap ignores)."""
    import cv2

    factor = _unit_factor(unit)
    _check_names(cameras, str(folder))
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    intri_path, extri_path = (folder / name for name in EASYMOCAP_FILES)
    intri = cv2.FileStorage(str(intri_path), cv2.FILE_STORAGE_WRITE)
    extri = cv2.FileStorage(str(extri_path), cv2.FILE_STORAGE_WRITE)
    for storage in (intri, extri):
        storage.startWriteStruct('names', cv2.FileNode_SEQ)
        for cam in cameras:
            storage.write('', cam.name)
        storage.endWriteStruct()
    for cam in cameras:
        R, t = _extrinsics(cam)
        intri.write(f'K_{cam.name}', cam.K)
        intri.write(f'dist_{cam.name}', _plumb_bob_only(cam, 'easymocap').reshape(1, 5))
        intri.write(f'W_{cam.name}', cam.width)
        intri.write(f'H_{cam.name}', cam.height)
        extri.write(f'R_{cam.name}', matrix_to_rotvec(R).reshape(3, 1))
        extri.write(f'Rot_{cam.name}', R)
        extri.write(f'T_{cam.name}', (t / factor).reshape(3, 1))
    intri.release()
    extri.release()
    return [intri_path, extri_path]


# ----------------------------------------------------------------------------- ROS
# camera_calibration
def _load_yaml(path: Path) -> dict:
    try:
        with open(path, encoding='utf-8') as stream:
            data = yaml.safe_load(stream)
    except (yaml.YAMLError, OSError) as exc:
        raise CalibrationError(
            f'{path}: not readable YAML ({" ".join(str(exc).split())})'
        ) from None
    if not isinstance(data, dict):
        raise CalibrationError(f'{path}: not a YAML mapping')
    return data


def read_ros_camera(path: str | Path, name: str | None = None) -> Camera:
    """Intrinsics of one ROS ``camera_calibration`` YAML.

    Pose at the origin: see :func:`read_ros`.
    """
    path = Path(path)
    data = _load_yaml(path)
    try:
        d = data.get('distortion_coefficients') or {}
        model = str(data.get('distortion_model', 'plumb_bob'))
        if model in ('equidistant', 'fisheye'):
            raise CalibrationError(f'{path}: fisheye (equidistant) distortion is not supported')
        return Camera.from_camera_info_fields(
            data['image_width'],
            data['image_height'],
            model,
            d.get('data') or [],
            data['camera_matrix']['data'],
            (data.get('rectification_matrix') or {}).get('data'),
            (data.get('projection_matrix') or {}).get('data'),
            name=name or ros_name(data.get('camera_name') or path.stem, 0),
        )
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, CalibrationError):
            raise
        raise CalibrationError(f'{path}: not a ROS camera calibration ({exc})') from None


def read_ros(path: str | Path, poses: str | Path | None = None) -> list[Camera]:
    """Cameras of ROS calibration YAMLs posed by a ``poses.yaml``.

    The folder, the poses file or one camera file.
    """
    path = Path(path)
    single = single_name = None
    if path.is_dir():
        poses_path = Path(poses) if poses else path / POSES_FILE
    elif 'camera_matrix' in _load_yaml(path):
        single, single_name = path, read_ros_camera(path).name
        poses_path = Path(poses) if poses else path.parent / POSES_FILE
    else:
        poses_path = path
    if not poses_path.is_file():
        raise CalibrationError(
            f'ROS calibration YAMLs carry no pose: no {poses_path} '
            f'(cameras: {{<name>: {{position: [x, y, z], orientation: [qx, qy, qz, qw]}}}})'
        )
    entries = _load_yaml(poses_path).get('cameras')
    if not isinstance(entries, dict) or not entries:
        raise CalibrationError(
            f'{poses_path}: needs "cameras:" mapping each camera to its position and orientation'
        )
    cameras = []
    for name, pose in entries.items():
        if single is not None and name != single_name:
            continue
        pose = pose or {}
        intrinsics = single or poses_path.parent / pose.get('calibration', f'{name}.yaml')
        if not intrinsics.is_file():
            raise CalibrationError(
                f'{poses_path}: no calibration file {intrinsics} for camera {name!r}'
            )
        cam = read_ros_camera(intrinsics, name=str(name))
        q = pose.get('orientation', (0.0, 0.0, 0.0, 1.0))
        position = pose.get('position', (0.0, 0.0, 0.0))
        if len(q) != 4 or len(position) != 3:
            raise CalibrationError(
                f'{poses_path}: camera {name!r} needs position [x, y, z] and orientation '
                '[qx, qy, qz, qw]'
            )
        cam.R_world_cam, cam.t_world_cam = (
            quat_to_matrix(np.asarray(q, float)),
            np.asarray(position, float),
        )
        cameras.append(cam)
    if not cameras:
        raise CalibrationError(f'{poses_path}: no pose for the camera of {single}')
    return cameras


def write_ros(cameras: list[Camera], folder: str | Path) -> list[Path]:
    """Write the cameras into ``folder`` in ROS camera_calibration layout.

    One ``<cam>.yaml`` per camera, and ``poses.yaml``.
    """
    _check_names(cameras, str(folder))
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written, poses = [], {}
    for cam in cameras:
        info = cam.to_camera_info_fields()
        data = {
            'image_width': cam.width,
            'image_height': cam.height,
            'camera_name': cam.name,
            'camera_matrix': {'rows': 3, 'cols': 3, 'data': info['k']},
            'distortion_model': info['distortion_model'],
            'distortion_coefficients': {'rows': 1, 'cols': len(info['d']), 'data': info['d']},
            'rectification_matrix': {'rows': 3, 'cols': 3, 'data': info['r']},
            'projection_matrix': {'rows': 3, 'cols': 4, 'data': info['p']},
        }
        path = folder / f'{cam.name}.yaml'
        path.write_text(
            yaml.safe_dump(data, sort_keys=False, default_flow_style=None), encoding='utf-8'
        )
        written.append(path)
        poses[cam.name] = {
            'position': [float(v) for v in cam.t_world_cam],
            'orientation': [float(v) for v in matrix_to_quat(cam.R_world_cam)],
        }
    path = folder / POSES_FILE
    header = (
        '# memo_ros camera poses: optical frame (z forward, x right, y down) of each camera in '
        'world,\n'
        '# position in metres, orientation quaternion [qx, qy, qz, qw]; intrinsics in '
        '<camera>.yaml\n'
    )
    path.write_text(
        header
        + yaml.safe_dump(
            {'frame_id': 'world', 'cameras': poses}, sort_keys=False, default_flow_style=None
        ),
        encoding='utf-8',
    )
    return written + [path]


# ----------------------------------------------------------------------------- detection and entry
# points
def detect_format(path: str | Path) -> str:
    """Return the format of a calibration file or folder, from its name and content."""
    path = Path(path)
    if not path.exists():
        raise CalibrationError(f'no calibration at {path}')
    if path.is_dir():
        if (path / EASYMOCAP_FILES[0]).is_file():
            return 'easymocap'
        if (path / POSES_FILE).is_file():
            return 'ros'
        found = {
            fmt: sorted(path.glob(pattern))
            for fmt, pattern in (('qualisys', '*.qca.txt'), ('toml', '*.toml'))
        }
        candidates = [fmt for fmt, files in found.items() if len(files) == 1]
        if len(candidates) == 1 and sum(map(len, found.values())) == 1:
            return candidates[0]
        raise CalibrationError(
            f'{path}: cannot tell the calibration format of this folder (expected intri.yml + '
            'extri.yml, poses.yaml + <camera>.yaml, or one .qca.txt or .toml)'
        )
    name = path.name.lower()
    head = path.read_bytes()[:4096].decode('utf-8', 'replace')
    if name.endswith('.qca.txt') or '<calibration' in head:
        return 'qualisys'
    if name.endswith('.toml'):
        return 'toml'
    if name in EASYMOCAP_FILES or 'opencv-matrix' in head:
        return 'easymocap'
    if name.endswith(('.yaml', '.yml')):
        if 'ros__parameters' in head:
            return 'studio'
        if 'camera_matrix' in head or re.search(r'^cameras\s*:', head, re.MULTILINE):
            return 'ros'
    raise CalibrationError(
        f'{path}: unknown calibration format (known: Qualisys .qca.txt, calibration.toml, '
        'EasyMocap intri.yml/extri.yml, ROS camera_calibration YAML + poses.yaml, '
        'memo_ros studio YAML)'
    )


def load_calibration(
    path: str | Path, fmt: str | None = None, unit: str = 'm', poses: str | Path | None = None
) -> Calibration:
    """Cameras of a calibration in any known format (detected unless ``fmt``).

    With caveats as notes.
    """
    path = Path(path)
    fmt = fmt or detect_format(path)
    size_known, notes = True, []
    if (
        fmt in ('qualisys', 'toml') and path.is_dir()
    ):  # detect_format found exactly one such file inside
        path = next(path.glob('*.qca.txt' if fmt == 'qualisys' else '*.toml'))
    if fmt == 'qualisys':
        cameras = read_qualisys(path)
    elif fmt == 'toml':
        cameras = read_toml(path, unit)
        notes += _far_camera_note(
            cameras, unit, 'the calibration unit, e.g. mm for Anipose/FreeMoCap'
        )
    elif fmt == 'easymocap':
        cameras, size_known = _read_easymocap(path, unit)
        notes += _far_camera_note(cameras, unit, 'the calibration unit')
        if not size_known:
            notes.append('EasyMocap stores no image size: taken from the videos')
    elif fmt == 'ros':
        cameras = read_ros(path, poses)
    elif fmt == 'studio':
        from memo_ros.core.formats.studio import Studio

        try:
            cameras = Studio.load(path).cameras
        except ValueError as exc:
            raise CalibrationError(str(exc)) from None
    else:
        raise CalibrationError(
            f'unknown calibration format {fmt!r} (known: {", ".join(READ_FORMATS)})'
        )
    _check_names(cameras, str(path))
    return Calibration(cameras, fmt, size_known, notes)


def read_calibration(path: str | Path, **options) -> list[Camera]:
    """Cameras of a calibration file or folder in any known format (:func:`load_calibration`)."""
    return load_calibration(path, **options).cameras


def write_calibration(
    cameras: list[Camera], path: str | Path, fmt: str, unit: str = 'm'
) -> list[Path]:
    """Write ``cameras`` as ``fmt``.

    a file (qualisys, toml) or a folder (easymocap, ros); the paths written.
    """
    if fmt == 'qualisys':
        return [write_qualisys(cameras, path)]
    if fmt == 'toml':
        return [write_toml(cameras, path, unit)]
    if fmt == 'easymocap':
        return write_easymocap(cameras, path, unit)
    if fmt == 'ros':
        return write_ros(cameras, path)
    raise CalibrationError(f'unknown calibration format {fmt!r} (known: {", ".join(FORMATS)})')


# default file or folder name inside an export folder, per format
DEFAULT_NAMES = {
    'qualisys': 'Calib.qca.txt',
    'toml': 'calibration.toml',
    'easymocap': '.',
    'ros': '.',
}
