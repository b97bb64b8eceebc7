"""Surface nodes of the parts with outward normals (the model "nodes" of Kakadiaris §4.1).

Each elliptic cylinder is tessellated into a grid on its side (rings along the
axis, points around the ellipse) and concentric rings on its two end caps.
Points and normals are in the part's own frame, so they stay constant while
the part moves (Kakadiaris eq. 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from memo_ros.core.geometry.body import PART_NAMES, Body, PartShape


@dataclass
class SurfaceNodes:
    """All parts' nodes.

    Owning part index, part-frame points and unit outward normals, neighbour indices.
    """

    part: np.ndarray  # (M,) int part index
    points: np.ndarray  # (M, 3) part frame
    normals: np.ndarray  # (M, 3) part frame, unit, outward
    neighbours: np.ndarray  # (M, K) global node indices of the nearest nodes on the same part

    def to_world(
        self, rotations: np.ndarray, origins: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Node positions and normals in world for part poses.

        The poses are rotations (P,3,3) and origins (P,3).
        """
        r = rotations[self.part]
        points = np.einsum('mij,mj->mi', r, self.points) + origins[self.part]
        normals = np.einsum('mij,mj->mi', r, self.normals)
        return points, normals


def part_surface(
    shape: PartShape, n_around: int = 24, n_along: int = 8, cap_rings: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Points and outward unit normals on one elliptic cylinder's side and caps (part frame)."""
    theta = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    cos, sin = np.cos(theta), np.sin(theta)
    z = np.linspace(0.0, shape.length, n_along)
    ring = np.stack([shape.a * cos, shape.b * sin], -1)
    ring_normal = np.stack([cos / shape.a, sin / shape.b], -1)
    ring_normal /= np.linalg.norm(ring_normal, axis=1, keepdims=True)
    side = np.concatenate(
        [np.repeat(ring[None], n_along, 0), np.repeat(z, n_around).reshape(n_along, n_around, 1)],
        -1,
    ).reshape(-1, 3)
    side_n = np.concatenate(
        [np.repeat(ring_normal[None], n_along, 0), np.zeros((n_along, n_around, 1))], -1
    ).reshape(-1, 3)
    points, normals = [side], [side_n]
    fractions = np.arange(1, cap_rings + 1) / (cap_rings + 1)
    for z_cap, sign in ((0.0, -1.0), (shape.length, 1.0)):
        cap_parts = [np.array([[0.0, 0.0, z_cap]])]
        for f in fractions:
            cap_parts.append(np.column_stack([f * ring, np.full(n_around, z_cap)]))
        cap = np.concatenate(cap_parts)
        points.append(cap)
        normals.append(np.tile([0.0, 0.0, sign], (len(cap), 1)))
    return np.concatenate(points), np.concatenate(normals)


def body_surface(
    body: Body, n_around: int = 24, n_along: int = 8, cap_rings: int = 2, n_neighbours: int = 4
) -> SurfaceNodes:
    """Nodes of every part, in part order, with each node's nearest neighbours on its part."""
    parts, points, normals, neighbours = [], [], [], []
    offset = 0
    for i, name in enumerate(PART_NAMES):
        p, n = part_surface(body.shapes[name], n_around, n_along, cap_rings)
        _, idx = cKDTree(p).query(p, k=n_neighbours + 1)
        parts.append(np.full(len(p), i))
        points.append(p)
        normals.append(n)
        neighbours.append(idx[:, 1:] + offset)
        offset += len(p)
    return SurfaceNodes(
        np.concatenate(parts),
        np.concatenate(points),
        np.concatenate(normals),
        np.concatenate(neighbours),
    )


def normal_variation(nodes: SurfaceNodes) -> np.ndarray:
    """Per-part variation of the normal, eps_i = mean over nodes of min_k n_m . n_k.

    Kakadiaris eq. 12.
    """
    eps_node = np.einsum('mj,mkj->mk', nodes.normals, nodes.normals[nodes.neighbours]).min(
        axis=1
    )  # eq. 12
    counts = np.bincount(nodes.part)
    return np.bincount(nodes.part, weights=eps_node) / counts
