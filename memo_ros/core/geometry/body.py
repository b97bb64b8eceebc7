"""Articulated body of 14 elliptic cylinders (Rohr §3.1) with a floating base.

Every part has its own frame: origin at its proximal joint centre (torso: the
pelvis centre), +z along the segment towards its distal end, and the two
semi-axes of its elliptic cross-section along x and y.  In the standing rest
pose the body faces +x of its torso frame (REP 103: x forward, y left, z up);
hanging limbs have x forward, y to the body's right and z down, the feet z
forward and x up.

Generalized coordinates ``q`` follow DESIGN.md: ``root_tx, root_ty, root_tz``
(pelvis centre in world, m), ``root_rx, root_ry, root_rz`` (torso rotation
vector, rad), then one entry per joint axis named ``<joint>_<axis>``.  Ball
joints (neck, shoulders, hips) use a rotation vector in the child's rest frame
(no gimbal lock); hinge-like joints use angles about the named axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from memo_ros.core.geometry.rotations import rot_x, rot_y, rot_z, rotvec_to_matrix

PART_NAMES: tuple[str, ...] = (
    'torso',
    'head',
    'upper_arm_l',
    'forearm_l',
    'hand_l',
    'upper_arm_r',
    'forearm_r',
    'hand_r',
    'thigh_l',
    'shank_l',
    'foot_l',
    'thigh_r',
    'shank_r',
    'foot_r',
)
JOINT_NAMES: tuple[str, ...] = (
    'neck',
    'shoulder_l',
    'elbow_l',
    'wrist_l',
    'shoulder_r',
    'elbow_r',
    'wrist_r',
    'hip_l',
    'knee_l',
    'ankle_l',
    'hip_r',
    'knee_r',
    'ankle_r',
)
ROOT_COORDINATES: tuple[str, ...] = (
    'root_tx',
    'root_ty',
    'root_tz',
    'root_rx',
    'root_ry',
    'root_rz',
)

# joint -> (parent part, child part, axes). 'ball' = rotation vector (x, y, z);
# otherwise the rotation is the product of elementary rotations in the order
# written, e.g. 'yz' = R_y(q_y) @ R_z(q_z): forearm twist first, then flexion.
JOINT_TREE: dict[str, tuple[str, str, str]] = {
    'neck': ('torso', 'head', 'ball'),
    'shoulder_l': ('torso', 'upper_arm_l', 'ball'),
    'elbow_l': ('upper_arm_l', 'forearm_l', 'yz'),
    'wrist_l': ('forearm_l', 'hand_l', 'yx'),
    'shoulder_r': ('torso', 'upper_arm_r', 'ball'),
    'elbow_r': ('upper_arm_r', 'forearm_r', 'yz'),
    'wrist_r': ('forearm_r', 'hand_r', 'yx'),
    'hip_l': ('torso', 'thigh_l', 'ball'),
    'knee_l': ('thigh_l', 'shank_l', 'y'),
    'ankle_l': ('shank_l', 'foot_l', 'y'),
    'hip_r': ('torso', 'thigh_r', 'ball'),
    'knee_r': ('thigh_r', 'shank_r', 'y'),
    'ankle_r': ('shank_r', 'foot_r', 'y'),
}

_HANGING = rot_x(np.pi)  # limb hanging down: x forward, y right, z down
_FOOT = rot_y(np.pi / 2)  # foot relative to shank: z forward, x up
_ELEMENTARY = {'x': rot_x, 'y': rot_y, 'z': rot_z}


@dataclass(frozen=True)
class PartShape:
    """An elliptic cylinder: length along z and semi-axes a (along x) and b (along y), metres."""

    length: float
    a: float
    b: float


@dataclass(frozen=True)
class JointSpec:
    """Where a child part hangs on its parent and how it may rotate."""

    name: str
    parent: int
    child: int
    axes: str
    offset: np.ndarray  # joint centre in the parent's frame
    rest: np.ndarray  # child's rest orientation in the parent's frame


@dataclass
class Body:
    """Kinematic tree of the 14 parts with shapes, joint offsets and coordinate names."""

    shapes: dict[str, PartShape]
    joint_offsets: dict[str, np.ndarray] = field(default_factory=dict)
    name: str = 'body'

    def __post_init__(self) -> None:
        missing = [p for p in PART_NAMES if p not in self.shapes]
        if missing:
            raise ValueError(f'body misses parts: {", ".join(missing)}')
        for part, shape in self.shapes.items():
            if min(shape.length, shape.a, shape.b) <= 0:
                raise ValueError(f'body part {part}: length and semi-axes must be positive')
        offsets = default_joint_offsets(self.shapes)
        offsets.update({k: np.asarray(v, float) for k, v in self.joint_offsets.items()})
        self.joint_offsets = offsets
        index = {p: i for i, p in enumerate(PART_NAMES)}
        self.joints: tuple[JointSpec, ...] = tuple(
            JointSpec(j, index[parent], index[child], axes, offsets[j], _rest_rotation(child))
            for j, (parent, child, axes) in JOINT_TREE.items()
        )
        names = list(ROOT_COORDINATES)
        for j in self.joints:
            names += [f'{j.name}_{axis}' for axis in ('xyz' if j.axes == 'ball' else j.axes)]
        self.coordinate_names: tuple[str, ...] = tuple(names)
        self._slices = {}
        start = len(ROOT_COORDINATES)
        for j in self.joints:
            n = 3 if j.axes == 'ball' else len(j.axes)
            self._slices[j.name] = slice(start, start + n)
            start += n
        self._rests = np.array([j.rest for j in self.joints])
        self._joint_kinds = _joint_kinds(self.joints, self._slices)
        self.lengths = np.array([self.shapes[p].length for p in PART_NAMES])
        self.semi_axes = np.array([[self.shapes[p].a, self.shapes[p].b] for p in PART_NAMES])

    @property
    def n_coordinates(self) -> int:
        """Return the number of generalized coordinates (6 root + the joint axes)."""
        return len(self.coordinate_names)

    def coordinate_index(self, name: str) -> int:
        """Index of a generalized coordinate by its JointState name."""
        return self.coordinate_names.index(name)

    def neutral(self) -> np.ndarray:
        """Standing rest pose with the lowest point of the feet on the ground (z = 0)."""
        q = np.zeros(self.n_coordinates)
        rotations, origins = self.forward_kinematics(q)
        q[2] = -lowest_point(self, rotations, origins)
        return q

    def forward_kinematics(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Part poses in world from generalized coordinates.

        Rotations (..., 14, 3, 3), origins (..., 14, 3).

        ``q`` may carry leading batch dimensions.  The chain is X_child = X_parent * T(offset) *
        R_rest * R_joint(q) (homogeneous transforms, Rohr §3.1).
        """
        q = np.asarray(q, float)
        batch = q.shape[:-1]
        rotations = np.empty(batch + (len(PART_NAMES), 3, 3))
        origins = np.empty(batch + (len(PART_NAMES), 3))
        rotations[..., 0, :, :] = rotvec_to_matrix(q[..., 3:6])
        origins[..., 0, :] = q[..., 0:3]
        local = self._rests @ self._joint_rotations(q)  # every child's frame in its parent's
        for k, j in enumerate(self.joints):
            parent_r = rotations[..., j.parent, :, :]
            rotations[..., j.child, :, :] = parent_r @ local[..., k, :, :]
            origins[..., j.child, :] = origins[..., j.parent, :] + parent_r @ j.offset
        return rotations, origins

    def _joint_rotations(self, q: np.ndarray) -> np.ndarray:
        """Rotation of every joint in its child's rest frame (..., J, 3, 3).

        From the coordinates (..., n): ball joints are rotation vectors; hinge-like joints the
        product of elementary rotations in the order written, each kind of joint computed in one
        batch.
        """
        out = np.empty(q.shape[:-1] + (len(self.joints), 3, 3))
        for axes, joints, cols in self._joint_kinds:
            if axes == 'ball':
                out[..., joints, :, :] = rotvec_to_matrix(q[..., cols])
                continue
            r = _ELEMENTARY[axes[0]](q[..., cols[:, 0]])
            for k in range(1, len(axes)):
                r = r @ _ELEMENTARY[axes[k]](q[..., cols[:, k]])
            out[..., joints, :, :] = r
        return out

    def joint_centres(self, origins: np.ndarray) -> np.ndarray:
        """Centres of the pelvis and the 13 joints (..., 14, 3): the points MPJPE measures."""
        return origins  # part origins are the proximal joint centres; torso's is the pelvis

    def distal_ends(self, rotations: np.ndarray, origins: np.ndarray) -> np.ndarray:
        """End point of every part's axis (..., 14, 3)."""
        return origins + rotations[..., :, 2] * self.lengths[:, None]

    def standing_height(self) -> float:
        """Height of the body standing in the rest pose: top of the head over the ground."""
        rotations, origins = self.forward_kinematics(self.neutral())
        return float(self.distal_ends(rotations, origins)[1, 2])

    def to_dict(self) -> dict:
        """Return the body as the studio YAML's ``body`` mapping."""
        return {
            'name': self.name,
            'parts': {
                p: {'length': float(s.length), 'semi_axes': [float(s.a), float(s.b)]}
                for p, s in ((p, self.shapes[p]) for p in PART_NAMES)
            },
            'joints': {j: [float(v) for v in self.joint_offsets[j]] for j in JOINT_NAMES},
        }

    @classmethod
    def from_dict(cls, data: dict) -> 'Body':
        """Build a body from the YAML ``body`` mapping.

        Parts: length, semi_axes; optional joints offsets.
        """
        try:
            parts = data['parts']
            shapes = {
                name: PartShape(
                    float(p['length']), float(p['semi_axes'][0]), float(p['semi_axes'][1])
                )
                for name, p in parts.items()
            }
        except (KeyError, TypeError, IndexError) as exc:
            raise ValueError(f'body: each part needs length and semi_axes [a, b] ({exc})') from exc
        unknown = set(shapes) - set(PART_NAMES)
        if unknown:
            raise ValueError(f'body: unknown parts {sorted(unknown)}')
        offsets = {}
        for joint, value in (data.get('joints') or {}).items():
            if joint not in JOINT_TREE:
                raise ValueError(f'body: unknown joint {joint!r}')
            offsets[joint] = np.asarray(value, float).reshape(3)
        return cls(shapes, offsets, str(data.get('name', 'body')))

    @classmethod
    def from_yaml(cls, path: str | Path) -> 'Body':
        """Load a body file (top-level ``body:`` mapping, or a studio YAML containing one)."""
        with open(path, encoding='utf-8') as stream:
            data = yaml.safe_load(stream)
        if not isinstance(data, dict) or 'body' not in data:
            raise ValueError(f'{path}: no "body" mapping')
        return cls.from_dict(data['body'])


def _joint_kinds(
    joints: tuple[JointSpec, ...], slices: dict[str, slice]
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Joints grouped by their axes.

    (axes, joint indices (m,), coordinate indices (m, axes' count)).
    """
    kinds: dict[str, list[int]] = {}
    for k, j in enumerate(joints):
        kinds.setdefault(j.axes, []).append(k)
    return [
        (
            axes,
            np.array(members),
            np.array(
                [range(slices[joints[k].name].start, slices[joints[k].name].stop) for k in members]
            ),
        )
        for axes, members in kinds.items()
    ]


SHOULDER_OUTSET = 0.6  # upper arm's axis outside the torso's side, in its half widths


def default_joint_offsets(shapes: dict[str, PartShape]) -> dict[str, np.ndarray]:
    """Joint centres in their parent's frame, derived from the part shapes.

    Shoulders at the torso's upper end, the upper arm's axis SHOULDER_OUTSET of its
    half width outside the torso's side: 380 mm apart at 1.75 m, near anatomy's 350
    (a whole half width, the arm hanging clear of the chest, puts them 420 mm apart,
    wider than a man's shoulders). Hips inside the pelvis (thigh flush with the
    torso's side), every distal joint at the end of its parent's axis.
    """
    torso, upper_arm, thigh = shapes['torso'], shapes['upper_arm_l'], shapes['thigh_l']
    shoulder_y = torso.b + SHOULDER_OUTSET * upper_arm.b
    shoulder_z = torso.length - 0.6 * upper_arm.a
    hip_y = torso.b - thigh.b
    offsets = {
        'neck': np.array([0.0, 0.0, torso.length]),
        'shoulder_l': np.array([0.0, shoulder_y, shoulder_z]),
        'shoulder_r': np.array([0.0, -shoulder_y, shoulder_z]),
        'hip_l': np.array([0.0, hip_y, 0.0]),
        'hip_r': np.array([0.0, -hip_y, 0.0]),
    }
    for joint, (parent, _child, _axes) in JOINT_TREE.items():
        if joint not in offsets:
            offsets[joint] = np.array([0.0, 0.0, shapes[parent].length])
    return offsets


def _rest_rotation(child: str) -> np.ndarray:
    if child in ('upper_arm_l', 'upper_arm_r', 'thigh_l', 'thigh_r'):
        return _HANGING
    if child.startswith('foot'):
        return _FOOT
    return np.eye(3)


def lowest_point(
    body: Body, rotations: np.ndarray, origins: np.ndarray, n_around: int = 32
) -> np.ndarray:
    """Lowest world z of the feet's surfaces (..., ): where the body touches the ground."""
    theta = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    lows = []
    for foot in (PART_NAMES.index('foot_l'), PART_NAMES.index('foot_r')):
        shape = body.shapes[PART_NAMES[foot]]
        ring = np.stack(
            [shape.a * np.cos(theta), shape.b * np.sin(theta), np.zeros_like(theta)], -1
        )
        pts = np.concatenate([ring, ring + [0.0, 0.0, shape.length]])
        world_z = (
            np.einsum('...j,nj->...n', rotations[..., foot, 2, :], pts)
            + origins[..., foot, 2, None]
        )
        lows.append(world_z.min(axis=-1))
    return np.minimum(*lows)


def other_side(name: str) -> str:
    """Return the same part or joint on the body's other side (itself on the midline)."""
    if name.endswith('_l'):
        return name[:-2] + '_r'
    if name.endswith('_r'):
        return name[:-2] + '_l'
    return name


def load_default_body() -> Body:
    """Return the shipped average adult (config/body_average_adult.yaml)."""
    from memo_ros.paths import config_path

    return Body.from_yaml(config_path('body_average_adult.yaml'))


def load_studio_actor() -> Body:
    """Return the simulated studios' person (config/body_studio_actor.yaml).

    The average adult with broad shoulders (420 mm): what the simulator renders by default.
    """
    from memo_ros.paths import config_path

    return Body.from_yaml(config_path('body_studio_actor.yaml'))
