"""The Jacobian L of body points with respect to the coordinates' local increments.

Kakadiaris eq. 2, 9.

A point p on part i moves with the increment delta of coordinate c by dp = axis_c x (p - pivot_c)
delta for a rotation and axis_c delta for the root's translation, when c lies on i's chain.
Rotation groups (root, ball joints) are perturbed on the right, R <- R exp(delta) (see motion.py),
so their axes are the child frame's columns; hinge chains ('yz', 'yx', 'y') take each elementary
axis after the rotations before it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.rotations import rot_x, rot_y, rot_z

_ELEMENTARY = {'x': rot_x, 'y': rot_y, 'z': rot_z}
_UNIT = {
    'x': np.array([1.0, 0.0, 0.0]),
    'y': np.array([0.0, 1.0, 0.0]),
    'z': np.array([0.0, 0.0, 1.0]),
}


@dataclass
class ChainAxes:
    """Per coordinate: world axis, pivot and kind, and which parts it moves (at one pose)."""

    axes: np.ndarray  # (n, 3)
    pivots: np.ndarray  # (n, 3)
    revolute: np.ndarray  # (n,) bool (False: root translation)
    affects: np.ndarray  # (P, n) bool

    @cached_property
    def rotation_axes(self) -> np.ndarray:
        """(3, n).

        The axes of the rotation coordinates as columns, zero for translations (see
        projected_rows).
        """
        return (self.axes * self.revolute[:, None]).T

    @cached_property
    def offset_terms(self) -> np.ndarray:
        """(3, n).

        -(a x c0) for a rotation about axis a through pivot c0, the axis a for a translation.
        """
        a, c = self.axes, self.pivots
        moment = a[:, [1, 2, 0]] * c[:, [2, 0, 1]] - a[:, [2, 0, 1]] * c[:, [1, 2, 0]]
        return np.where(self.revolute[:, None], -moment, a).T


def chain_membership(body: Body) -> np.ndarray:
    """(P, n) True where coordinate c moves part i (c on the path from the root to i)."""
    n_parts = len(PART_NAMES)
    affects = np.zeros((n_parts, body.n_coordinates), bool)
    affects[:, :6] = True
    parent_joint = {j.child: j for j in body.joints}
    for i in range(n_parts):
        part = i
        while part in parent_joint:
            joint = parent_joint[part]
            affects[i, body._slices[joint.name]] = True
            part = joint.parent
    return affects


def chain_axes(
    body: Body,
    q: np.ndarray,
    rotations: np.ndarray,
    origins: np.ndarray,
    affects: np.ndarray | None = None,
) -> ChainAxes:
    """Axes and pivots of every coordinate at pose q.

    Rotations/origins from forward kinematics of q.
    """
    n = body.n_coordinates
    axes = np.zeros((n, 3))
    pivots = np.zeros((n, 3))
    revolute = np.ones(n, bool)
    axes[0:3] = np.eye(3)
    revolute[0:3] = False
    axes[3:6] = rotations[0].T  # columns of the torso frame
    pivots[3:6] = origins[0]
    for joint in body.joints:
        cols = body._slices[joint.name]
        pivots[cols] = origins[joint.child]
        if joint.axes == 'ball':
            axes[cols] = rotations[joint.child].T
            continue
        frame = rotations[joint.parent] @ joint.rest
        for k, letter in enumerate(joint.axes):
            axes[cols.start + k] = frame @ _UNIT[letter]
            if k + 1 < len(joint.axes):  # the next axis turns with this rotation
                frame = frame @ _ELEMENTARY[letter](q[cols.start + k])
    return ChainAxes(
        axes, pivots, revolute, chain_membership(body) if affects is None else affects
    )


def point_jacobian(chain: ChainAxes, parts: np.ndarray, points: np.ndarray) -> np.ndarray:
    """L: dp/d(delta) (N, 3, n) for world points on ``parts`` (Kakadiaris eq. 9's L)."""
    lever = points[:, None, :] - chain.pivots[None]  # (N, n, 3)
    cols = np.where(
        chain.revolute[None, :, None],
        np.cross(chain.axes[None], lever),
        np.broadcast_to(chain.axes[None], lever.shape),
    )
    cols = cols * chain.affects[parts][:, :, None]
    return np.swapaxes(cols, 1, 2)


def normal_jacobian(
    chain: ChainAxes, parts: np.ndarray, normals: np.ndarray, part_axes: np.ndarray
) -> np.ndarray:
    """dn/d(delta) (N, 3, n) of contour-generator normals.

    Rotations move them, except a twist about the part's own axis, which leaves the generator's
    normal in place (eq. 15's L).
    """
    w = chain.axes[None] * chain.revolute[None, :, None]  # (1, n, 3)
    along = part_axes[:, None, :]  # (N, 1, 3)
    w_perp = w - np.sum(w * along, -1, keepdims=True) * along
    cols = np.cross(w_perp, normals[:, None, :]) * chain.affects[parts][:, :, None]
    return np.swapaxes(cols, 1, 2)


def projected_rows(
    chain: ChainAxes, parts: np.ndarray, points: np.ndarray, g: np.ndarray
) -> np.ndarray:
    """G .

    L (N, n) for world points and row vectors g (N, 3), without forming L (eq. 9 contracted).

    For a rotation c about axis a through pivot c0, g . (a x (p - c0)) = a . (p x g) - g . (a x
    c0), so all columns come from two (N, 3) @ (3, n) products; a translation column is g . a.
    Equal to ``einsum('ni,nij->nj', g, point_jacobian(chain, parts, points))``.
    """
    p_cross_g = points[:, [1, 2, 0]] * g[:, [2, 0, 1]] - points[:, [2, 0, 1]] * g[:, [1, 2, 0]]
    rows = p_cross_g @ chain.rotation_axes + g @ chain.offset_terms
    rows *= chain.affects[parts]
    return rows
