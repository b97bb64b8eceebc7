"""Force assignment (Kakadiaris & Metaxas §4.1): tie each occluding-contour sample to a model node.

Step 1: at every contour sample z, the tangent t_z and the normal k_z of the plane
through the camera centre, z and t_z (oriented away from the silhouette).
Step 2: the candidate nodes of a part are those whose normal n satisfies
n . k_z >= eps_i (eq. 13).  Step 3: z goes to the candidate whose projection is
nearest, within a gate; samples that fit no candidate are dropped, not forced.

Candidates are the nodes that can lie on the predicted outline: per ring, the
two points of the part's exact contour generator (see model_nodes.py) and the
rim nodes whose normal fan can face the camera's ray, minus those the rendered
predicted body hides (its depth image shows a surface clearly in front).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from memo_ros.core.camera import Camera
from memo_ros.core.model_nodes import ModelNodes, fan_alignment

NEIGHBOURS = 8             # nearest projected candidates examined per contour sample
OCCLUSION_TOLERANCE_M = 0.05   # a surface this much nearer than a node at its pixel hides it
RIM_VIEW_COS = 0.35        # a rim node may be on the outline when its fan holds a normal within ~20 deg of perpendicular


@dataclass
class ContourRays:
    """Step 1 for one camera's samples: pixel, outward image normal m and plane normal k_z (world)."""

    uv: np.ndarray        # (N, 2)
    outward: np.ndarray   # (N, 2) unit image normal pointing away from the silhouette, (-ty, tx)
    k: np.ndarray         # (N, 3) unit world normal of the plane through centre, z and t_z


def contour_rays(camera: Camera, table: np.ndarray) -> ContourRays:
    """k_z for every contour sample (Step 1), oriented to point out of the silhouette like the surface normal."""
    x = np.asarray(table['x'], float)
    y = np.asarray(table['y'], float)
    tx = np.asarray(table['tx'], float)
    ty = np.asarray(table['ty'], float)
    outward = np.stack([-ty, tx], -1)
    d_z = camera.pixel_rays(x, y)
    d_t = camera.pixel_rays(x + tx, y + ty)
    d_o = camera.pixel_rays(x + outward[:, 0], y + outward[:, 1])
    k = np.cross(d_z, d_t)
    k /= np.maximum(np.linalg.norm(k, axis=1, keepdims=True), 1e-12)
    k *= np.where(np.einsum('ni,ni->n', k, d_o) < 0, -1.0, 1.0)[:, None]
    return ContourRays(np.stack([x, y], -1), outward, k)


@dataclass
class Candidates:
    """Model nodes that may lie on a camera's silhouette outline at a pose (world frame)."""

    part: np.ndarray       # (C,)
    points: np.ndarray     # (C, 3)
    normal: np.ndarray     # (C, 3) generator normal (side) or side normal of the rim node
    cap: np.ndarray        # (C, 3) cap normal (rim nodes), zeros for side nodes
    rim: np.ndarray        # (C,) bool
    uv: np.ndarray         # (C, 2)

    def __len__(self) -> int:
        return len(self.part)


def silhouette_candidates(camera: Camera, nodes: ModelNodes, rotations: np.ndarray, origins: np.ndarray,
                          depth: np.ndarray | None = None, depth_scale: float = 1.0) -> Candidates:
    """The generator points of every side ring and the outward-facing rim nodes, on the silhouette."""
    centre = np.asarray(camera.t_world_cam, float)
    r_node = rotations[nodes.part]
    centre_local = np.einsum('mji,mj->mi', r_node, centre - origins[nodes.part])
    # side: one node per ring and generator (the ring's nodes nearest the two generator lines, moved onto them)
    side = nodes.rim == 0
    ring_start = side & (np.abs(np.angle(np.exp(1j * nodes.theta))) < 1e-9)
    idx = np.flatnonzero(ring_start)
    theta = np.concatenate([_both_generators(nodes, centre_local, idx, s) for s in (1.0, -1.0)])
    idx2 = np.concatenate([idx, idx])
    ok = np.isfinite(theta)
    idx2, theta = idx2[ok], theta[ok]
    local = np.stack([nodes.a[idx2] * np.cos(theta), nodes.b[idx2] * np.sin(theta), nodes.z[idx2]], -1)
    n_local = np.stack([np.cos(theta) / nodes.a[idx2], np.sin(theta) / nodes.b[idx2], np.zeros_like(theta)], -1)
    n_local /= np.linalg.norm(n_local, axis=1, keepdims=True)
    # rims: nodes whose normal fan holds a direction (nearly) perpendicular to the ray
    rim_idx = np.flatnonzero(~side)
    rim_local = nodes.local_points()[rim_idx]
    rim_n = nodes.side_normals()[rim_idx]
    rim_cap = np.zeros_like(rim_n)
    rim_cap[:, 2] = nodes.rim[rim_idx]
    view = rim_local - centre_local[rim_idx]
    s_dot, c_dot = np.einsum('mi,mi->m', rim_n, view), np.einsum('mi,mi->m', rim_cap, view)
    norm = np.linalg.norm(view, axis=1)
    keep = (s_dot * c_dot <= 0) | (np.abs(s_dot) <= RIM_VIEW_COS * norm) | (np.abs(c_dot) <= RIM_VIEW_COS * norm)
    rim_idx = rim_idx[keep]
    all_idx = np.concatenate([idx2, rim_idx])
    part = nodes.part[all_idx]
    r = rotations[part]
    local_all = np.concatenate([local, rim_local[keep]])
    points = np.einsum('mij,mj->mi', r, local_all) + origins[part]
    normal = np.einsum('mij,mj->mi', r, np.concatenate([n_local, rim_n[keep]]))
    cap = np.einsum('mij,mj->mi', r, np.concatenate([np.zeros_like(n_local), rim_cap[keep]]))
    rim = np.concatenate([np.zeros(len(idx2), bool), np.ones(int(keep.sum()), bool)])
    uv = camera.project(points)
    visible = np.all(np.isfinite(uv), axis=1)
    if depth is not None:
        visible &= ~_occluded(depth, depth_scale, uv, camera.world_to_camera(points)[:, 2])
    return Candidates(part[visible], points[visible], normal[visible], cap[visible], rim[visible], uv[visible])


def _both_generators(nodes: ModelNodes, centre_local: np.ndarray, idx: np.ndarray, sign: float) -> np.ndarray:
    """Generator angle on one side (sign +1: phi + arccos, -1: phi - arccos) for the rings starting at idx."""
    ux, uy = centre_local[idx, 0] / nodes.a[idx], centre_local[idx, 1] / nodes.b[idx]
    rho = np.hypot(ux, uy)
    with np.errstate(invalid='ignore', divide='ignore'):
        half = np.where(rho > 1.0, np.arccos(np.clip(1.0 / rho, -1.0, 1.0)), np.nan)
    return np.arctan2(uy, ux) + sign * half


def _occluded(depth: np.ndarray, scale: float, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    """True where the rendered depth image shows a surface clearly in front of the point (occlusion test)."""
    h, w = depth.shape
    col = np.round((uv[:, 0] + 0.5) * scale - 0.5).astype(int)
    row = np.round((uv[:, 1] + 0.5) * scale - 0.5).astype(int)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    out = np.zeros(len(uv), bool)
    out[inside] = depth[row[inside], col[inside]] < z[inside] - OCCLUSION_TOLERANCE_M
    return out


@dataclass
class Matches:
    """Contour samples tied to candidate nodes (Step 3)."""

    sample: np.ndarray     # (N,) index into the camera's contour table
    node: np.ndarray       # (N,) index into the candidates
    distance: np.ndarray   # (N,) pixels between the sample and the node's projection


def assign_forces(rays: ContourRays, candidates: Candidates, epsilon: np.ndarray, gate_px: float) -> Matches:
    """Each sample to the nearest projected candidate that passes eq. 13 within ``gate_px`` (Steps 2-3)."""
    empty = Matches(np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    if not len(candidates) or not len(rays.uv):
        return empty
    k = min(NEIGHBOURS, len(candidates))
    dist, idx = cKDTree(candidates.uv).query(rays.uv, k=k, distance_upper_bound=gate_px)
    dist, idx = dist.reshape(len(rays.uv), k), idx.reshape(len(rays.uv), k)
    found = idx < len(candidates)
    safe = np.where(found, idx, 0)
    kz = np.broadcast_to(rays.k[:, None, :], safe.shape + (3,)).reshape(-1, 3)
    side_align = np.einsum('mi,mi->m', candidates.normal[safe].reshape(-1, 3), kz)
    rim_align = fan_alignment(candidates.normal[safe].reshape(-1, 3), candidates.cap[safe].reshape(-1, 3), kz)
    align = np.where(candidates.rim[safe].reshape(-1), rim_align, side_align).reshape(safe.shape)
    ok = found & (align >= epsilon[candidates.part[safe]])                           # eq. 13
    has = ok.any(axis=1)
    first = np.argmax(ok, axis=1)
    rows = np.flatnonzero(has)
    return Matches(rows, idx[rows, first[rows]], dist[rows, first[rows]])
