"""What the body's shape cannot tell but its anatomy can.

Joint ranges, facing, and the mirror twin.

The 14 elliptic cylinders are front/back symmetric except the feet, so a body
turned by 180 degrees about the vertical, with its left and right limbs
exchanged and its hinges bent the other way, casts the same silhouettes: the
*twin* of a pose.  Only anatomy separates the two: knees flex backwards and
elbows forwards (hard ranges, in Rohr's spirit of a model that only allows
human postures), and the feet point forwards.  :func:`twin_pose` builds the
twin so that the tracker can keep it as a competing hypothesis.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from memo_ros.core.geometry.body import JOINT_TREE, ROOT_COORDINATES, Body, other_side
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.rotations import matrix_to_rotvec, rot_z, rotvec_to_matrix

# anatomical ranges of the hinge coordinates, rad (elbows and knees cannot hyperextend), and of
# the neck's rotation vector: bent sideways up to 45 degrees, forwards or back up to 57, turned up
# to 80 (a head turned further is the same cylinder turned by pi the other way: turned_head)
JOINT_LIMITS: dict[str, tuple[float, float]] = {
    'neck_x': (-0.8, 0.8),
    'neck_y': (-1.0, 1.0),
    'neck_z': (-1.4, 1.4),
    'elbow_l_y': (0.0, 2.6),
    'elbow_r_y': (0.0, 2.6),
    'wrist_l_y': (-1.3, 1.3),
    'wrist_r_y': (-1.3, 1.3),
    'wrist_l_x': (-0.6, 0.6),
    'wrist_r_x': (-0.6, 0.6),
    'knee_l_y': (-2.6, 0.0),
    'knee_r_y': (-2.6, 0.0),
    'ankle_l_y': (-0.9, 0.9),
    'ankle_r_y': (-0.9, 0.9),
}
# the turn by pi about the body's own vertical: rotations about x and y change sign, about z not
TWIN_SIGN = {'x': -1.0, 'y': -1.0, 'z': 1.0}
# the mirror in the body's sagittal (x-z) plane: rotations about x and z change sign, about y not
MIRROR_SIGN = {'x': -1.0, 'y': 1.0, 'z': -1.0}
# the joints of each pair of limbs, from the torso out (their left and right coordinates exchange)
LIMB_JOINTS: dict[str, tuple[str, ...]] = {
    'legs': ('hip', 'knee', 'ankle'),
    'arms': ('shoulder', 'elbow', 'wrist'),
}
# an elbow bent backwards by more than this is the same arm with the upper arm turned about its
# axis
ELBOW_REFLEX = 0.2  # rad; below it a slightly negative elbow is only clamped to straight


class Anatomy:
    """Index tables of one body's coordinates.

    Ranges, hinge angles to wrap, the twin's permutation.
    """

    def __init__(self, body: Body) -> None:
        names = body.coordinate_names
        self.n = len(names)
        self.limit_index = np.array([names.index(n) for n in JOINT_LIMITS], int)
        self.limit_low = np.array([lo for lo, _ in JOINT_LIMITS.values()])
        self.limit_high = np.array([hi for _, hi in JOINT_LIMITS.values()])
        hinges = [
            names.index(f'{joint}_{axis}')
            for joint, (_parent, _child, axes) in JOINT_TREE.items()
            if axes != 'ball'
            for axis in axes
        ]
        self.wrap_index = np.array(sorted(set(hinges) - set(self.limit_index)), int)
        self.neck = names.index('neck_x')
        self.arms = [
            (
                names.index(f'shoulder_{side}_x'),
                names.index(f'elbow_{side}_y'),
                names.index(f'elbow_{side}_z'),
            )
            for side in ('l', 'r')
        ]
        self.twin_source = np.arange(self.n)
        self.twin_sign = np.ones(self.n)
        for k, name in enumerate(names):
            if name in ROOT_COORDINATES:
                continue
            joint, axis = name.rsplit('_', 1)
            other = other_side(joint)
            self.twin_source[k] = names.index(f'{other}_{axis}')
            self.twin_sign[k] = TWIN_SIGN[axis]

        self.limbs = {pair: _limb_exchange(names, joints) for pair, joints in LIMB_JOINTS.items()}
        self.hip_twists = np.array([names.index(f'hip_{side}_z') for side in ('l', 'r')], int)

    def difference(self, q: np.ndarray, pair: str) -> np.ndarray:
        """Return the left limb's coordinates less the mirror of the right's (0 if symmetric)."""
        left, right, sign = self.limbs[pair]
        q = np.asarray(q, float)
        return q[left] - sign * q[right]

    def exchange(self, q: np.ndarray, pair: str) -> tuple[np.ndarray, np.ndarray]:
        """Return ``q`` with the pair's left and right limbs exchanged, and its tangent map.

        Each limb takes the other's angles mirrored in the sagittal plane, so
        the raised leg of a kick becomes the other leg raised the same way;
        the torso and the other pair stay.  The pose a side view cannot tell
        from ``q``, which a fast limb motion can leave the filter in.
        """
        left, right, sign = self.limbs[pair]
        out = np.array(q, float)
        out[left], out[right] = sign * out[right], sign * out[left]
        M = np.eye(self.n)
        M[left, left] = M[right, right] = 0.0
        M[left, right] = M[right, left] = sign
        return out, M

    def reflexed_arms(self, q: np.ndarray) -> list[tuple[int, int, int]]:
        """Return (shoulder, elbow_y, elbow_z) indices of every arm whose elbow bends backwards."""
        return [arm for arm in self.arms if q[arm[1]] < -ELBOW_REFLEX]

    def unreflex(self, q: np.ndarray, arm: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Return the same arm with its elbow bent forwards, and the map of its tangent vectors.

        The upper arm turned by pi about its own axis (the shoulder's rotation
        times R_z(pi)) with the elbow's flexion negated and its twist less pi
        puts every part exactly where it was: R_z(pi) R_y(-e) R_z(t - pi) =
        R_y(e) R_z(t).  The elbow's anatomical range then holds without
        moving the arm, which a clamp alone would straighten.
        """
        shoulder, elbow_y, elbow_z = arm
        out = np.array(q, float)
        turned = rotvec_to_matrix(out[shoulder : shoulder + 3]) @ rot_z(np.pi)
        out[shoulder : shoulder + 3] = matrix_to_rotvec(turned)
        out[elbow_y] = -out[elbow_y]
        out[elbow_z] = out[elbow_z] - np.pi
        M = np.eye(self.n)
        M[shoulder, shoulder] = M[shoulder + 1, shoulder + 1] = -1.0  # body rates turn with it
        M[elbow_y, elbow_y] = -1.0
        return out, M

    def head_turned_back(self, q: np.ndarray) -> bool:
        """Return whether the head is turned by more than 90 degrees from the torso."""
        return float(np.linalg.norm(np.asarray(q, float)[self.neck : self.neck + 3])) > np.pi / 2

    def turned_head(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the head turned by pi about its own axis, and the map of its tangent vectors.

        The head is an elliptic cylinder on its own axis with no part below it, so the neck's
        rotation times R_z(pi) puts it exactly where it was: a head that silhouettes left turned
        the wrong way round faces forwards again, and the neck's range then holds.
        """
        out = np.array(q, float)
        neck = slice(self.neck, self.neck + 3)
        out[neck] = matrix_to_rotvec(rotvec_to_matrix(out[neck]) @ rot_z(np.pi))
        M = np.eye(self.n)
        M[self.neck, self.neck] = M[self.neck + 1, self.neck + 1] = -1.0  # rates turn with it
        return out, M

    def project(self, q: np.ndarray) -> np.ndarray:
        """Return ``q`` with backward-bent elbows and a head turned back turned round, clamped."""
        out = np.array(q, float)
        for arm in self.reflexed_arms(out):
            out, _ = self.unreflex(out, arm)
        if self.head_turned_back(out):
            out, _ = self.turned_head(out)
        return self.clamp(out)

    def clamp(self, q: np.ndarray) -> np.ndarray:
        """Project ``q`` into the anatomical ranges; wrap the other hinge angles into (-pi, pi]."""
        out = np.array(q, float)
        out[..., self.limit_index] = np.clip(
            out[..., self.limit_index], self.limit_low, self.limit_high
        )
        wrapped = out[..., self.wrap_index]
        out[..., self.wrap_index] = np.pi - np.mod(np.pi - wrapped, 2 * np.pi)
        return out

    def outside(self, q: np.ndarray) -> np.ndarray:
        """How far each limited coordinate lies outside its range, rad (0 inside)."""
        v = np.asarray(q, float)[..., self.limit_index]
        return np.maximum(self.limit_low - v, 0.0) + np.maximum(v - self.limit_high, 0.0)

    def twin(self, q: np.ndarray) -> np.ndarray:
        """Return the pose turned by pi about the pelvis' vertical with left and right exchanged.

        Every part except the feet covers the same volume as in ``q``: the root
        keeps its position and turns about its own z axis, and each joint takes
        the other side's angles with the signs of a turn about z (x and y
        flip, z stays), which reverses the hinges' bending.
        """
        q = np.asarray(q, float)
        out = q[..., self.twin_source] * self.twin_sign
        out[..., 0:3] = q[..., 0:3]
        out[..., 3:6] = matrix_to_rotvec(rotvec_to_matrix(q[..., 3:6]) @ rot_z(np.pi))
        return out

    def tangent_map(self) -> np.ndarray:
        """Return the twin's map of tangent vectors (rates, covariances).

        M with v_twin = M v, (n, n).

        Joints as :meth:`twin`; the root's body-frame rates turn with it (about x and y they change
        sign), its translation rates stay.
        """
        M = np.zeros((self.n, self.n))
        M[np.arange(self.n), self.twin_source] = self.twin_sign
        M[3:6, 3:6] = np.diag([-1.0, -1.0, 1.0])
        return M


def _limb_exchange(names: Sequence[str], joints: Sequence[str]) -> tuple:
    """Return the indices of a pair's left and right coordinates and the mirror's signs."""
    left = [k for k, n in enumerate(names) if n.rsplit('_', 2)[0] in joints and '_l_' in n]
    right = [names.index(n.replace('_l_', '_r_')) for n in (names[k] for k in left)]
    sign = np.array([MIRROR_SIGN[names[k].rsplit('_', 1)[1]] for k in left])
    return np.array(left, int), np.array(right, int), sign


def facing(body: Body, q: np.ndarray) -> np.ndarray:
    """Heading of the torso's forward (+x) axis about the world z axis, rad (..., )."""
    rotations, _ = body.forward_kinematics(q)
    forward = rotations[..., 0, :, 0]
    return np.arctan2(forward[..., 1], forward[..., 0])


def studio_volume(
    cameras: Sequence[Camera],
    depth: float = 20.0,
    margin: float = 2.0,
    z_range: tuple[float, float] = (-1.0, 4.0),
) -> tuple[np.ndarray, np.ndarray] | None:
    """Return the box (low, high) in which a body's root can be: None without cameras.

    Horizontally, the bounding box of the cameras' centres and of what their
    image corners and centres see up to ``depth`` metres away, grown by
    ``margin`` metres; vertically ``z_range`` (world z up, the floor at 0).
    """
    points: list[np.ndarray] = []
    for camera in cameras:
        w, h = camera.width - 1.0, camera.height - 1.0
        u = np.array([0.0, w, 0.0, w, 0.5 * w])
        v = np.array([0.0, 0.0, h, h, 0.5 * h])
        with np.errstate(all='ignore'):
            seen = camera.centre + depth * camera.pixel_rays(u, v)
        points += [camera.centre[None], seen[np.all(np.isfinite(seen), axis=1)]]
    if not points:
        return None
    xy = np.concatenate(points)[:, :2]
    low = np.append(xy.min(axis=0) - margin, z_range[0])
    high = np.append(xy.max(axis=0) + margin, z_range[1])
    return low, high


def pose_problem(
    body: Body,
    q: np.ndarray,
    volume: tuple[np.ndarray, np.ndarray] | None,
    limit_tolerance: float = 0.1,
    limits: bool = True,
) -> str | None:
    """Return why ``q`` is no pose of a person in the studio (one line), or None when it is one.

    The root must lie inside ``volume`` (:func:`studio_volume`; None: anywhere),
    every hinge with an anatomical range (JOINT_LIMITS) within it up to
    ``limit_tolerance`` rad (not checked with ``limits`` false, e.g. for an
    extrapolated pose), every other angle within 2 pi of zero and every
    rotation vector (the root's and the ball joints') no longer than 2 pi.
    """
    names = body.coordinate_names
    try:
        q = np.asarray(q, float)
    except (TypeError, ValueError):
        return 'the coordinates are not numbers'
    if q.shape != (len(names),):
        return f'a pose needs {len(names)} coordinates, got shape {q.shape}'
    bad = [n for n, value in zip(names, q) if not np.isfinite(value)]
    if bad:
        return f'not finite: {", ".join(bad[:4])}{" ..." if len(bad) > 4 else ""}'
    if volume is not None:
        low, high = (np.asarray(b, float) for b in volume)
        root = q[:3]
        if np.any(root < low) or np.any(root > high):
            box = ', '.join(
                f'{axis} [{lo:.1f}, {hi:.1f}]' for axis, lo, hi in zip('xyz', low, high)
            )
            return (
                f'the root at ({root[0]:.4g}, {root[1]:.4g}, {root[2]:.4g}) m is outside the '
                f'studio volume ({box} m)'
            )
    if limits:
        for name, (lo, hi) in JOINT_LIMITS.items():
            if name in names:
                value = q[names.index(name)]
                if value < lo - limit_tolerance or value > hi + limit_tolerance:
                    return f'{name} = {value:.4g} rad is outside its range [{lo:g}, {hi:g}] rad'
    groups = [('root', names.index('root_rx'))] + [
        (j.name, names.index(f'{j.name}_x')) for j in body.joints if j.axes == 'ball'
    ]
    in_groups: set[int] = set()
    for joint, start in groups:
        in_groups.update(range(start, start + 3))
        angle = float(np.linalg.norm(q[start : start + 3]))
        if angle > 2 * np.pi:
            return f'the rotation vector of {joint} is {angle:.4g} rad long (more than 2 pi)'
    for k, name in enumerate(names):
        if k >= len(ROOT_COORDINATES) and k not in in_groups and abs(q[k]) > 2 * np.pi:
            return f'{name} = {q[k]:.4g} rad is more than 2 pi from zero'
    return None
