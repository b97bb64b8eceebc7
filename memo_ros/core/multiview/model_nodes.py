"""The tracker's model nodes: rings of points on every part's side, whose outer rings are the rims.

Kakadiaris & Metaxas tie each occluding-contour sample to a node of the
tessellated part (§4.1).  Our parts are exact elliptic cylinders, so a side node
that eq. 13 selects is moved around its ring onto the exact contour generator
for the camera (the surface line whose normal is perpendicular to the viewing
ray): the image force (eq. 14) and the normal force (eq. 15) are then zero at
the true pose instead of carrying the tessellation's quantisation.  The first
and last ring are rims (the edge between side and end cap): their normals span
the fan from the side normal to the cap normal.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.surface import body_surface, normal_variation


@dataclass
class ModelNodes:
    """Nodes of all parts in part frames.

    Ring angle, height, rim flag, with per-part eq. 12 thresholds.
    """

    part: np.ndarray  # (M,) part index
    theta: np.ndarray  # (M,) angle around the ellipse, rad
    z: np.ndarray  # (M,) height along the part's axis, m
    rim: np.ndarray  # (M,) 0 = side, -1 = proximal rim, +1 = distal rim
    a: np.ndarray  # (M,) semi-axis along the part's x
    b: np.ndarray  # (M,) semi-axis along the part's y
    epsilon: np.ndarray  # (P,) eps_i, the part's normal variation (eq. 12)

    def __len__(self) -> int:
        return len(self.part)

    def local_points(self, theta: np.ndarray | None = None) -> np.ndarray:
        """Part-frame points (M, 3), optionally at other ring angles."""
        theta = self.theta if theta is None else theta
        return np.stack([self.a * np.cos(theta), self.b * np.sin(theta), self.z], -1)

    def side_normals(self, theta: np.ndarray | None = None) -> np.ndarray:
        """Part-frame unit outward side normals (M, 3) at the ring angles."""
        theta = self.theta if theta is None else theta
        n = np.stack([np.cos(theta) / self.a, np.sin(theta) / self.b, np.zeros_like(theta)], -1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    # fixed per body: precomputed once, used at every relinearisation
    @cached_property
    def ring_starts(self) -> np.ndarray:
        """Index of the first node (angle 0) of every side ring."""
        return np.flatnonzero((self.rim == 0) & (np.abs(np.angle(np.exp(1j * self.theta))) < 1e-9))

    @cached_property
    def side_index(self) -> np.ndarray:
        """Ring starts twice.

        The side candidates' rings, first on the +arccos generator, then on the -arccos one.
        """
        return np.concatenate([self.ring_starts, self.ring_starts])

    @cached_property
    def side_sign(self) -> np.ndarray:
        """+1 / -1: the generator of each entry of :attr:`side_index`."""
        return np.repeat([1.0, -1.0], len(self.ring_starts))

    @cached_property
    def rim_index(self) -> np.ndarray:
        """Indices of the rim nodes."""
        return np.flatnonzero(self.rim != 0)

    @cached_property
    def rim_points(self) -> np.ndarray:
        """Part-frame positions of the rim nodes."""
        return self.local_points()[self.rim_index]

    @cached_property
    def rim_normals(self) -> np.ndarray:
        """Part-frame side normals of the rim nodes."""
        return self.side_normals()[self.rim_index]


def model_nodes(body: Body, n_around: int = 24, ring_spacing: float = 0.03) -> ModelNodes:
    """Rings every ``ring_spacing`` m along each part, ends included, ``n_around`` nodes a ring."""
    theta_ring = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    parts, thetas, zs, rims, a, b = [], [], [], [], [], []
    for i, name in enumerate(PART_NAMES):
        shape = body.shapes[name]
        rings = max(int(np.ceil(shape.length / ring_spacing)) + 1, 3)
        z = np.linspace(0.0, shape.length, rings)
        rim = np.zeros(rings, int)
        rim[0], rim[-1] = -1, 1
        parts.append(np.full(rings * n_around, i))
        thetas.append(np.tile(theta_ring, rings))
        zs.append(np.repeat(z, n_around))
        rims.append(np.repeat(rim, n_around))
        a.append(np.full(rings * n_around, shape.a))
        b.append(np.full(rings * n_around, shape.b))
    epsilon = normal_variation(body_surface(body, n_around=n_around))  # eq. 12
    return ModelNodes(
        np.concatenate(parts),
        np.concatenate(thetas),
        np.concatenate(zs),
        np.concatenate(rims),
        np.concatenate(a),
        np.concatenate(b),
        epsilon,
    )


def fan_alignment(side_n: np.ndarray, cap_n: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Max over the rim's normal fan (side to cap, a quarter turn) of n . k (M,).

    Eq. 13 for rim nodes.
    """
    s = side_n[:, 0] * k[:, 0] + side_n[:, 1] * k[:, 1] + side_n[:, 2] * k[:, 2]
    c = cap_n[:, 0] * k[:, 0] + cap_n[:, 1] * k[:, 1] + cap_n[:, 2] * k[:, 2]
    inside = (s > 0) & (c > 0)
    return np.where(inside, np.hypot(s, c), np.maximum(s, c))
