"""The studio file: cameras, body and node parameters in one ROS 2 params YAML.

The file is a valid ``--ros-args --params-file`` (rcl refuses any value outside
``<node>: ros__parameters:``), so the shared description lives under the
wildcard ``/**`` as nested parameters that every node may declare::

    /**:
      ros__parameters:
        studio:
          name: studio_orthogonal
          frame_rate: 30.0
          cameras: [cam_front, cam_side, cam_top]
          cam_front: {width: 640, height: 480, distortion_model: plumb_bob,
                      K: [...9], D: [...], position: [x, y, z], orientation: [qx, qy, qz, qw]}
        body:
          name: average_adult_175
          torso: {length: 0.56, semi_axes: [0.11, 0.16]}
          ...
          joints: {shoulder_l: [x, y, z], ...}      # optional
        initial_pose: {names: [...], positions: [...]}   # optional
    /**/contour_node:                 # every contour_node, whatever its camera namespace
      ros__parameters: {...}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import yaml

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.camera import Camera

WILDCARD = '/**'


@dataclass
class Studio:
    """A calibrated rig, the body it observes and the graph's node parameters."""

    name: str
    cameras: list[Camera]
    body: Body
    frame_rate: float = 30.0
    node_parameters: dict[str, dict] = field(default_factory=dict)
    initial_pose: dict[str, float] = field(default_factory=dict)

    def camera(self, name: str) -> Camera:
        """Return the camera called ``name``."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise KeyError(f'studio {self.name!r} has no camera {name!r}')

    @property
    def camera_names(self) -> list[str]:
        """Return the studio's camera names, in the file's order."""
        return [c.name for c in self.cameras]

    def to_yaml_dict(self) -> dict:
        """Return the params-file mapping (see the module docstring)."""
        studio = {
            'name': self.name,
            'frame_rate': float(self.frame_rate),
            'cameras': self.camera_names,
        }
        for cam in self.cameras:
            studio[cam.name] = _camera_entry(cam)
        body = self.body.to_dict()
        body_params = {'name': body['name'], 'joints': body['joints']}
        body_params.update(body['parts'])
        shared = {'studio': studio, 'body': body_params}
        if self.initial_pose:
            shared['initial_pose'] = {
                'names': list(self.initial_pose),
                'positions': [float(v) for v in self.initial_pose.values()],
            }
        data = {WILDCARD: {'ros__parameters': shared}}
        for node, params in self.node_parameters.items():
            # '/**/name' so that a node in any namespace (one contour_node per camera) gets them
            data[f'{WILDCARD}/{node}'] = {'ros__parameters': params}
        return data

    def save(self, path: str | Path) -> None:
        """Write the studio as a params YAML."""
        text = yaml.safe_dump(
            self.to_yaml_dict(), sort_keys=False, default_flow_style=None, width=120
        )
        Path(path).write_text(
            f'# memo_ros studio {self.name}: use with --ros-args --params-file\n{text}',
            encoding='utf-8',
        )

    @classmethod
    def from_yaml_dict(cls, data: dict, source: str = 'studio') -> 'Studio':
        """Parse the params-file mapping."""
        try:
            shared = data[WILDCARD]['ros__parameters']
            studio = shared['studio']
            names = list(studio['cameras'])
        except (KeyError, TypeError) as exc:
            raise ValueError(
                f'{source}: not a memo_ros studio file (needs /**: ros__parameters: studio: '
                f'cameras: [...]); missing {exc}'
            ) from exc
        cameras = [_camera_from_entry(name, studio.get(name), source) for name in names]
        body_params = dict(shared.get('body') or {})
        if body_params:
            parts = {p: body_params[p] for p in PART_NAMES if p in body_params}
            body = Body.from_dict(
                {
                    'name': body_params.get('name', 'body'),
                    'parts': parts,
                    'joints': body_params.get('joints') or {},
                }
            )
        else:
            from memo_ros.core.geometry.body import load_default_body

            body = load_default_body()
        pose = shared.get('initial_pose') or {}
        initial = dict(zip(pose.get('names', []), map(float, pose.get('positions', []))))
        nodes = {
            k.removeprefix(WILDCARD).strip('/'): v.get('ros__parameters', {})
            for k, v in data.items()
            if k != WILDCARD and isinstance(v, dict)
        }
        return cls(
            str(studio.get('name', 'studio')),
            cameras,
            body,
            float(studio.get('frame_rate', 30.0)),
            nodes,
            initial,
        )

    @classmethod
    def load(cls, path: str | Path) -> 'Studio':
        """Read a studio params YAML."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f'no studio file at {path}')
        try:
            with open(path, encoding='utf-8') as stream:
                data = yaml.safe_load(stream)
        except UnicodeDecodeError:
            raise ValueError(f'{path}: not a text (UTF-8) file') from None
        except yaml.YAMLError as exc:
            raise ValueError(f'{path}: not YAML ({" ".join(str(exc).split())[:120]})') from None
        if not isinstance(data, dict):
            raise ValueError(f'{path}: not a YAML mapping')
        return cls.from_yaml_dict(data, str(path))


def _camera_entry(cam: Camera) -> dict:
    entry = cam.to_dict()
    entry.pop('name', None)
    pose = entry.pop('pose')
    entry['position'] = [float(v) for v in pose['position']]
    entry['orientation'] = [float(v) for v in pose['orientation']]
    entry['K'] = [float(v) for v in entry['K']]
    entry['D'] = [float(v) for v in entry['D']]
    return entry


def _camera_from_entry(name: str, entry, source: str) -> Camera:
    if not isinstance(entry, dict):
        raise ValueError(f'{source}: camera {name!r} listed but not described under studio.{name}')
    data = dict(entry)
    data['name'] = name
    data['pose'] = {
        'position': data.pop('position', [0.0, 0.0, 0.0]),
        'orientation': data.pop('orientation', [0.0, 0.0, 0.0, 1.0]),
    }
    try:
        return Camera.from_dict(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f'{source}: camera {name!r}: {exc}') from exc


def studio_path(path_or_name: str | Path) -> Path:
    """Return a studio file's path.

    As given, or a shipped studio by name (e.g. 'studio_orthogonal').
    """
    path = Path(path_or_name)
    if not path.is_file() and path.suffix == '' and not path.parent.parts:
        from memo_ros.paths import config_path

        return config_path(f'{path_or_name}.yaml')
    return path


def load_studio(path_or_name: str | Path) -> Studio:
    """Load a studio from a path, or a shipped one by name."""
    return Studio.load(studio_path(path_or_name))
