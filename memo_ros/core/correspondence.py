"""Force assignment (Kakadiaris & Metaxas §4.1): tie each occluding-contour sample to a model node.

Step 1: at every contour sample z, the tangent t_z and the normal k_z of the plane
through the camera centre, z and t_z (oriented away from the silhouette).
Step 2: the candidate nodes of a part are those whose normal n satisfies
n . k_z >= eps_i (eq. 13).  Step 3: z goes to the candidate whose projection is
nearest, within a gate; samples that fit no candidate are dropped, not forced.
Optionally the assignment is made symmetric: every candidate also pulls on its
nearest eq. 13-compatible sample, so a predicted outline with no contour under
it (a limb sticking out of the silhouette where the camera sees none) is pulled
back instead of going unnoticed.

Candidates are the nodes that can lie on the predicted outline: per ring, the
two points of the part's exact contour generator (see model_nodes.py) and the
rim nodes whose normal fan can face the camera's ray, kept only where the
predicted body does not hide them and where just outside them (``probe_px``
beyond the node, across the outline) the predicted body leaves background:
a node inside another part's silhouette is not on any occluding contour.  Both
tests cast rays exactly against the parts' elliptic cylinders (no rendering).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from memo_ros.core.camera import Camera
from memo_ros.core.model_nodes import ModelNodes, fan_alignment

NEIGHBOURS = 8             # nearest projected candidates examined per contour sample
RAY_TOLERANCE_M = 0.01     # the same for the exact ray test
RIM_VIEW_COS = 0.35        # a rim node may be on the outline when its fan holds a normal within ~20 deg of perpendicular
OUTLINE_PROBE_PX = 2.0     # a node is on the outline when the body leaves background this far outside it


@dataclass
class ContourRays:
    """Step 1 for one camera's samples: pixel, outward image normal m and plane normal k_z (world)."""

    uv: np.ndarray        # (N, 2)
    outward: np.ndarray   # (N, 2) unit image normal pointing away from the silhouette, (-ty, tx)
    k: np.ndarray         # (N, 3) unit world normal of the plane through centre, z and t_z
    bias: np.ndarray | None = None   # (N,) px the contour's smoothing is thought to have moved each sample
    _tree: cKDTree | None = field(default=None, init=False, repr=False)

    @property
    def tree(self) -> cKDTree:
        """KD-tree of the samples' pixels (built once per frame, for the candidates' nearest samples)."""
        if self._tree is None:
            self._tree = cKDTree(self.uv)
        return self._tree


def smoothing_shift(table: np.ndarray, smoothing: float) -> np.ndarray:
    """(N,) px along the outward normal that undo the contour's Gaussian smoothing to first order.

    Low-passing a closed curve along its arc with a Gaussian of ``smoothing`` px moves each point towards its
    centre of curvature by about smoothing^2 kappa / 2 (a circle of radius rho shrinks by rho (1 - exp(-s^2 /
    2 rho^2))): convex tips (a hand's end) retract, concave corners (where a part meets a wider one) fill in.
    kappa is the signed curvature of the smoothed contour, from its neighbouring tangents; the shift is
    capped at half the smoothing, where the first-order model no longer holds.
    """
    n = len(table)
    if smoothing <= 0 or n < 3:
        return np.zeros(n)
    contour = np.asarray(table['contour'])
    starts = np.flatnonzero(np.r_[True, contour[1:] != contour[:-1]])
    lengths = np.diff(np.r_[starts, n])
    start = np.repeat(starts, lengths)
    length = np.repeat(lengths, lengths)
    pos = np.arange(n) - start
    nxt, prv = start + (pos + 1) % length, start + (pos - 1) % length
    x, y = np.asarray(table['x'], float), np.asarray(table['y'], float)
    tx, ty = np.asarray(table['tx'], float), np.asarray(table['ty'], float)
    arc = np.hypot(x[nxt] - x[prv], y[nxt] - y[prv])
    turn = np.arctan2(tx[prv] * ty[nxt] - ty[prv] * tx[nxt], tx[prv] * tx[nxt] + ty[prv] * ty[nxt])
    kappa = np.where((arc > 1e-6) & (length >= 3), turn / np.maximum(arc, 1e-6), 0.0)
    # the outward normal is (-ty, tx): a tangent turning towards it (positive turn in image coordinates,
    # y down) bends the curve away from the silhouette, i.e. a concave corner; convex parts turn the other way
    return np.clip(-0.5 * smoothing ** 2 * kappa, -0.5 * smoothing, 0.5 * smoothing)


def contour_rays(camera: Camera, table: np.ndarray, smoothing: float = 0.0, shift: bool = False) -> ContourRays:
    """k_z for every contour sample (Step 1), oriented to point out of the silhouette like the surface normal;
    ``bias`` holds :func:`smoothing_shift` for the contour's Gaussian ``smoothing`` (px), by which the samples
    are moved back when ``shift``."""
    x = np.asarray(table['x'], float)
    y = np.asarray(table['y'], float)
    tx = np.asarray(table['tx'], float)
    ty = np.asarray(table['ty'], float)
    outward = np.stack([-ty, tx], -1)
    bias = smoothing_shift(table, smoothing)
    if shift:
        x, y = x + bias * outward[:, 0], y + bias * outward[:, 1]
    d = camera.pixel_rays(np.concatenate([x, x + tx]), np.concatenate([y, y + ty]))   # one undistortion call
    d_z, d_t = d[:len(x)], d[len(x):]
    k = np.cross(d_z, d_t)
    k /= np.maximum(np.linalg.norm(k, axis=1, keepdims=True), 1e-12)
    # orient k out of the silhouette: the camera maps image orientation consistently, so one outward ray
    # (of a sample with a tangent) fixes the sign for all
    j = int(np.argmax(np.hypot(tx, ty))) if len(x) else 0
    if len(x):
        d_o = camera.pixel_rays(x[j:j + 1] + outward[j:j + 1, 0], y[j:j + 1] + outward[j:j + 1, 1])[0]
        if k[j] @ d_o < 0:
            k = -k
    return ContourRays(np.stack([x, y], -1), outward, k, bias)


@dataclass
class Candidates:
    """Model nodes that may lie on a camera's silhouette outline at a pose (world frame)."""

    part: np.ndarray       # (C,)
    points: np.ndarray     # (C, 3)
    normal: np.ndarray     # (C, 3) generator normal (side) or side normal of the rim node
    cap: np.ndarray        # (C, 3) cap normal (rim nodes), zeros for side nodes
    rim: np.ndarray        # (C,) bool
    uv: np.ndarray         # (C, 2)
    key: np.ndarray | None = None       # (C,) identity of the node (ring and generator side, or rim node)
    outline: np.ndarray | None = None   # (C, 3) unit outward normal of the outline at the node, across the ray
    usable: np.ndarray | None = None    # (C,) on the predicted outline; None = all.  The others only absorb
                                        # the samples nearest to them (ambiguous: a narrow gap, a hidden edge)

    def __len__(self) -> int:
        return len(self.part)

    def subset(self, keep: np.ndarray) -> 'Candidates':
        """The candidates selected by a mask or index array."""
        return Candidates(self.part[keep], self.points[keep], self.normal[keep], self.cap[keep], self.rim[keep],
                          self.uv[keep], None if self.key is None else self.key[keep],
                          None if self.outline is None else self.outline[keep],
                          None if self.usable is None else self.usable[keep])


def outline_candidates(camera: Camera, nodes: ModelNodes, rotations: np.ndarray, origins: np.ndarray,
                       keys: np.ndarray | None = None) -> Candidates:
    """Every node that can be on an outline by its own shape: the generator points of each side ring and the
    rim nodes whose normal fan can face across the ray (no test against the other parts); only the nodes
    named by ``keys`` (see :attr:`Candidates.key`) when given."""
    centre = np.asarray(camera.t_world_cam, float)
    # side: one node per ring and generator (the ring's nodes nearest the two generator lines, moved onto them)
    if keys is None:
        idx = np.concatenate([nodes.ring_starts, nodes.ring_starts])
        sign = np.repeat([1.0, -1.0], len(nodes.ring_starts))
        rim_sel = np.arange(len(nodes.rim_index))
    else:
        side_keys = keys[keys < 2 * len(nodes)]
        idx, sign = side_keys // 2, np.where(side_keys % 2 == 0, 1.0, -1.0)
        rim_sel = np.searchsorted(nodes.rim_index, keys[keys >= 2 * len(nodes)] - 2 * len(nodes))
    part_s = nodes.part[idx]
    centre_local = np.einsum('mji,mj->mi', rotations[part_s], centre - origins[part_s])
    theta = _generator(nodes, centre_local, idx, sign)
    key_side = 2 * idx + (sign < 0)
    ok = np.isfinite(theta)
    idx2, theta, key_side = idx[ok], theta[ok], key_side[ok]
    local = np.stack([nodes.a[idx2] * np.cos(theta), nodes.b[idx2] * np.sin(theta), nodes.z[idx2]], -1)
    n_local = np.stack([np.cos(theta) / nodes.a[idx2], np.sin(theta) / nodes.b[idx2], np.zeros_like(theta)], -1)
    n_local /= np.linalg.norm(n_local, axis=1, keepdims=True)
    # rims: nodes whose normal fan holds a direction (nearly) perpendicular to the ray
    rim_idx = nodes.rim_index[rim_sel]
    rim_local = nodes.rim_points[rim_sel]
    rim_n = nodes.rim_normals[rim_sel]
    rim_cap = nodes.rim_caps[rim_sel]
    part_r = nodes.part[rim_idx]
    view = rim_local - np.einsum('mji,mj->mi', rotations[part_r], centre - origins[part_r])
    s_dot, c_dot = np.einsum('mi,mi->m', rim_n, view), np.einsum('mi,mi->m', rim_cap, view)
    norm = np.linalg.norm(view, axis=1)
    keep = (s_dot * c_dot <= 0) | (np.abs(s_dot) <= RIM_VIEW_COS * norm) | (np.abs(c_dot) <= RIM_VIEW_COS * norm)
    part = np.concatenate([nodes.part[idx2], nodes.part[rim_idx[keep]]])
    r = rotations[part]
    local_all = np.concatenate([local, rim_local[keep]])
    points = np.einsum('mij,mj->mi', r, local_all) + origins[part]
    normal = np.einsum('mij,mj->mi', r, np.concatenate([n_local, rim_n[keep]]))
    cap = np.einsum('mij,mj->mi', r, np.concatenate([np.zeros_like(n_local), rim_cap[keep]]))
    rim = np.concatenate([np.zeros(len(idx2), bool), np.ones(int(keep.sum()), bool)])
    key = np.concatenate([key_side, 2 * len(nodes) + rim_idx[keep]])
    uv = camera.project(points)
    outline = _outline_normals(points - centre, normal, cap, rim)
    return Candidates(part, points, normal, cap, rim, uv, key, outline)


def _outline_normals(view: np.ndarray, side: np.ndarray, cap: np.ndarray, rim: np.ndarray) -> np.ndarray:
    """Unit normal of the outline at each node, perpendicular to the viewing ray: the generator normal for
    side nodes, and for rim nodes the direction of their fan (side to cap) that is perpendicular to the ray."""
    v = view / np.linalg.norm(view, axis=1, keepdims=True)
    s_dot, c_dot = np.einsum('mi,mi->m', side, v), np.einsum('mi,mi->m', cap, v)
    in_fan = rim & (s_dot * c_dot <= 0)
    fan = c_dot[:, None] * side - s_dot[:, None] * cap
    fan *= np.where(np.einsum('mi,mi->m', fan, side + cap) < 0, -1.0, 1.0)[:, None]
    extreme = np.where((np.abs(s_dot) <= np.abs(c_dot))[:, None], side, cap)
    n = np.where(in_fan[:, None], fan, np.where(rim[:, None], extreme, side))
    n = n - np.einsum('mi,mi->m', n, v)[:, None] * v
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def ray_hits(centre: np.ndarray, directions: np.ndarray, rotations: np.ndarray, origins: np.ndarray,
             semi_axes: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Distance (C, P) along each unit ray from ``centre`` to every part's capped elliptic cylinder (inf = miss)."""
    o = np.einsum('pji,pj->pi', rotations, centre - origins)[:, None, :]  # ray origin in each part frame (P, 1, 3)
    d = np.matmul(directions[None], rotations)                            # directions in each part frame (P, C, 3)
    a, b = semi_axes[:, 0, None], semi_axes[:, 1, None]
    length = lengths[:, None]
    ox, oy, oz = o[..., 0] / a, o[..., 1] / b, o[..., 2]
    dx, dy, dz = d[..., 0] / a, d[..., 1] / b, d[..., 2]
    qa = dx * dx + dy * dy
    qb = 2.0 * (ox * dx + oy * dy)
    qc = ox * ox + oy * oy - 1.0
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(invalid='ignore', divide='ignore'):
        s_side = (-qb - np.sqrt(disc)) / (2.0 * qa)
        z_side = oz + s_side * dz
        best = np.where((disc >= 0) & (s_side > 0) & (z_side >= 0) & (z_side <= length), s_side, np.inf)
        for z_cap in (0.0, length):
            s_cap = (z_cap - oz) / dz
            x = ox + s_cap * dx
            y = oy + s_cap * dy
            best = np.where((s_cap > 0) & (x * x + y * y <= 1.0) & (s_cap < best), s_cap, best)
    return best.T


def on_outline(camera: Camera, cand: Candidates, rotations: np.ndarray, origins: np.ndarray,
               semi_axes: np.ndarray, lengths: np.ndarray, probe_px: float = OUTLINE_PROBE_PX) -> np.ndarray:
    """(C,) True where a candidate is on the predicted body's occluding contour: nothing hides it, and the ray
    ``probe_px`` outside it across the outline meets no part (it is not inside another part's silhouette)."""
    centre = np.asarray(camera.t_world_cam, float)
    view = cand.points - centre
    dist = np.linalg.norm(view, axis=1)
    focal = float(camera.K[0, 0])
    probe = view + (probe_px * dist / focal)[:, None] * cand.outline   # probe_px in the image, to first order
    dirs = np.concatenate([view / dist[:, None], probe / np.linalg.norm(probe, axis=1, keepdims=True)])
    hits = ray_hits(centre, dirs, rotations, origins, semi_axes, lengths)
    n = len(cand)
    hidden = np.any(hits[:n] < (dist - RAY_TOLERANCE_M)[:, None], axis=1)
    covered = np.any(np.isfinite(hits[n:]), axis=1)
    return ~hidden & ~covered & np.all(np.isfinite(cand.uv), axis=1)


def _generator(nodes: ModelNodes, centre_local: np.ndarray, idx: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """Generator angle of the rings starting at idx, on the side ``sign`` (+1: phi + arccos, -1: phi - arccos),
    for the camera centre in each ring's part frame; NaN when the centre is inside the cylinder."""
    ux, uy = centre_local[:, 0] / nodes.a[idx], centre_local[:, 1] / nodes.b[idx]
    rho = np.hypot(ux, uy)
    with np.errstate(invalid='ignore', divide='ignore'):
        half = np.where(rho > 1.0, np.arccos(np.clip(1.0 / rho, -1.0, 1.0)), np.nan)
    return np.arctan2(uy, ux) + sign * half


@dataclass
class Matches:
    """Contour samples tied to candidate nodes (Step 3)."""

    sample: np.ndarray     # (N,) index into the camera's contour table
    node: np.ndarray       # (N,) index into the candidates
    distance: np.ndarray   # (N,) pixels between the sample and the node's projection


def _alignment(rays: ContourRays, candidates: Candidates, sample: np.ndarray, node: np.ndarray) -> np.ndarray:
    """n . k_z of each (sample, node) pair, over the rim's normal fan for rim nodes (eq. 13's left side)."""
    kz = rays.k[sample]
    side_align = np.einsum('mi,mi->m', candidates.normal[node], kz)
    rim_align = fan_alignment(candidates.normal[node], candidates.cap[node], kz)
    return np.where(candidates.rim[node], rim_align, side_align)


def _first_compatible(dist, idx, n_targets, align_fn, threshold_fn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows whose nearest neighbours hold one passing eq. 13: (rows, neighbour index, distance)."""
    dist, idx = dist.reshape(len(dist), -1), idx.reshape(len(idx), -1)
    found = idx < n_targets
    safe = np.where(found, idx, 0)
    rows = np.repeat(np.arange(len(idx)), idx.shape[1])
    ok = found & (align_fn(rows, safe.reshape(-1)) >= threshold_fn(rows, safe.reshape(-1))).reshape(safe.shape)
    has = ok.any(axis=1)
    first = np.argmax(ok, axis=1)
    sel = np.flatnonzero(has)
    return sel, idx[sel, first[sel]], dist[sel, first[sel]]


def assign_forces(rays: ContourRays, candidates: Candidates, epsilon: np.ndarray, gate_px: float,
                  symmetric: bool = False) -> Matches:
    """Each sample to the nearest projected candidate that passes eq. 13 within ``gate_px`` (Steps 2-3); with
    ``symmetric`` also each candidate to its nearest eq. 13-compatible sample (pairs counted once)."""
    empty = Matches(np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    if not len(candidates) or not len(rays.uv):
        return empty
    k = min(NEIGHBOURS, len(candidates))
    dist, idx = cKDTree(candidates.uv).query(rays.uv, k=k, distance_upper_bound=gate_px)
    eps = epsilon[candidates.part]
    sample, node, d = _first_compatible(dist, idx, len(candidates),
                                        lambda s, c: _alignment(rays, candidates, s, c),
                                        lambda s, c: eps[c])                              # eq. 13
    if candidates.usable is not None:                 # nearest node not on the outline: ambiguous, dropped
        ok = candidates.usable[node]
        sample, node, d = sample[ok], node[ok], d[ok]
    if not symmetric:
        return Matches(sample, node, d)
    k = min(NEIGHBOURS, len(rays.uv))
    pullers = np.arange(len(candidates)) if candidates.usable is None else np.flatnonzero(candidates.usable)
    dist, idx = rays.tree.query(candidates.uv[pullers], k=k, distance_upper_bound=gate_px)
    node_b, sample_b, d_b = _first_compatible(dist, idx, len(rays.uv),
                                              lambda c, s: _alignment(rays, candidates, s, pullers[c]),
                                              lambda c, s: eps[pullers[c]])               # eq. 13
    node_b = pullers[node_b]
    pair = np.concatenate([sample * len(candidates) + node, sample_b * len(candidates) + node_b])
    _, first = np.unique(pair, return_index=True)
    return Matches(np.concatenate([sample, sample_b])[first], np.concatenate([node, node_b])[first],
                   np.concatenate([d, d_b])[first])
