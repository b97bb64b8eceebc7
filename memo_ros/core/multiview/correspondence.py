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

from memo_ros.core.geometry.camera import Camera
from memo_ros.core.multiview.model_nodes import ModelNodes, fan_alignment

NEIGHBOURS = 8  # nearest projected candidates examined per contour sample
RAY_TOLERANCE_M = 0.01  # the same for the exact ray test
# a rim node may be on the outline when its fan holds a normal within ~20 deg of perpendicular
RIM_VIEW_COS = 0.35
OUTLINE_PROBE_PX = (
    2.0  # a node is on the outline when the body leaves background this far outside it
)
_BOX_CORNERS = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (0.0, 1.0)])


@dataclass
class ContourRays:
    """Step 1 for one camera's samples: pixel, outward image normal m, world plane normal k_z."""

    uv: np.ndarray  # (N, 2)
    outward: np.ndarray  # (N, 2) unit image normal pointing away from the silhouette, (-ty, tx)
    k: np.ndarray  # (N, 3) unit world normal of the plane through centre, z and t_z
    bias: np.ndarray | None = (
        None  # (N,) px the contour's smoothing is thought to have moved each sample
    )
    _tree: cKDTree | None = field(default=None, init=False, repr=False)

    @property
    def tree(self) -> cKDTree:
        """KD-tree of the samples' pixels.

        Built once per frame, for the candidates' nearest samples.
        """
        if self._tree is None:
            self._tree = cKDTree(self.uv)
        return self._tree

    def within(self, uv: np.ndarray, radius: float) -> np.ndarray:
        """(C,) True where some sample lies closer than ``radius`` px to each finite point ``uv``.

        C, 2.

        A grid of cells whose diagonal is under ``radius`` settles every point sharing a cell with
        a sample; only the others are looked up in the KD-tree (the same answer, without a query
        per point).
        """
        out = np.zeros(len(uv), bool)
        if not len(self.uv) or not len(uv):
            return out
        cell = radius / np.sqrt(2.0) * (1.0 - 1e-9)
        lo = np.floor(self.uv.min(axis=0) / cell)
        ij = (np.floor(self.uv / cell) - lo).astype(np.intp)
        shape = ij.max(axis=0) + 1
        occupied = np.zeros(shape, bool)
        occupied[ij[:, 0], ij[:, 1]] = True
        kl = np.floor(uv / cell) - lo
        inside = np.all((kl >= 0) & (kl < shape), axis=1)
        kl = kl[inside].astype(np.intp)
        out[np.flatnonzero(inside)[occupied[kl[:, 0], kl[:, 1]]]] = True
        rest = np.flatnonzero(~out)
        if len(rest):
            out[rest] = np.isfinite(self.tree.query(uv[rest], k=1, distance_upper_bound=radius)[0])
        return out


def thinned_samples(table: np.ndarray, budget: int) -> np.ndarray:
    """Return every k-th sample of each contour of ``table``, k the least that keeps <= ``budget``.

    The tracker's cost grows with the samples while a contour sampled every 2 px says little
    more than one sampled every 6 px; the noise per sample follows the spacing (sample_spacing).
    0 or a table within the budget: the table itself.
    """
    n = len(table)
    if budget <= 0 or n <= budget:
        return table
    k = int(np.ceil(n / budget))
    contour = (
        np.asarray(table['contour'])
        if 'contour' in (table.dtype.names or ())
        else np.zeros(n, np.uint32)
    )
    _start, _length, pos = _contour_positions(contour)
    return table[pos % k == 0]


def _contour_positions(contour: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per sample: its contour's first index, its contour's length, and its place along it.

    ``contour``: each sample's contour id, the samples of a contour consecutive.
    """
    n = len(contour)
    starts = np.flatnonzero(np.concatenate(([True], contour[1:] != contour[:-1])))
    lengths = np.diff(starts, append=n)
    start = np.repeat(starts, lengths)
    return start, np.repeat(lengths, lengths), np.arange(n) - start


def smoothing_shift(table: np.ndarray, smoothing: float) -> np.ndarray:
    """(N,) px along the outward normal that undo the contour's Gaussian smoothing to first order.

    Low-passing a closed curve along its arc with a Gaussian of ``smoothing`` px moves each point
    towards its centre of curvature by about smoothing^2 kappa / 2 (a circle of radius rho shrinks
    by rho (1 - exp(-s^2 / 2 rho^2))): convex tips (a hand's end) retract, concave corners (where a
    part meets a wider one) fill in. kappa is the signed curvature of the smoothed contour, from
    its neighbouring tangents; the shift is capped at half the smoothing, where the first-order
    model no longer holds.
    """
    n = len(table)
    if smoothing <= 0 or n < 3:
        return np.zeros(n)
    start, length, pos = _contour_positions(np.asarray(table['contour']))
    nxt, prv = start + (pos + 1) % length, start + (pos - 1) % length
    x, y = np.asarray(table['x'], float), np.asarray(table['y'], float)
    tx, ty = np.asarray(table['tx'], float), np.asarray(table['ty'], float)
    arc = np.hypot(x[nxt] - x[prv], y[nxt] - y[prv])
    turn = np.arctan2(tx[prv] * ty[nxt] - ty[prv] * tx[nxt], tx[prv] * tx[nxt] + ty[prv] * ty[nxt])
    kappa = np.where((arc > 1e-6) & (length >= 3), turn / np.maximum(arc, 1e-6), 0.0)
    # the outward normal is (-ty, tx): a tangent turning towards it (positive turn in image
    # coordinates,
    # y down) bends the curve away from the silhouette, i.e. a concave corner; convex parts turn
    # the other way
    return np.clip(-0.5 * smoothing**2 * kappa, -0.5 * smoothing, 0.5 * smoothing)


def contour_rays(
    camera: Camera, table: np.ndarray, smoothing: float = 0.0, shift: bool = False
) -> ContourRays:
    """k_z for every contour sample (Step 1).

    Oriented to point out of the silhouette like the surface normal; ``bias`` holds
    :func:`smoothing_shift` for the contour's Gaussian ``smoothing`` (px), by which the samples are
    moved back when ``shift``.
    """
    x = np.asarray(table['x'], float)
    y = np.asarray(table['y'], float)
    tx = np.asarray(table['tx'], float)
    ty = np.asarray(table['ty'], float)
    outward = np.stack([-ty, tx], -1)
    bias = smoothing_shift(table, smoothing)
    if shift:
        x, y = x + bias * outward[:, 0], y + bias * outward[:, 1]
    # orient k out of the silhouette: the camera maps image orientation consistently, so one
    # outward ray
    # (of a sample with a tangent) fixes the sign for all
    n = len(x)
    j = int(np.argmax(np.hypot(tx, ty))) if n else 0
    d = camera.pixel_rays(
        np.concatenate([x, x + tx, x[j : j + 1] + outward[j : j + 1, 0]]),  # one undistortion call
        np.concatenate([y, y + ty, y[j : j + 1] + outward[j : j + 1, 1]]),
    )
    d_z, d_t = d[:n], d[n : 2 * n]
    k = d_z[:, [1, 2, 0]] * d_t[:, [2, 0, 1]] - d_z[:, [2, 0, 1]] * d_t[:, [1, 2, 0]]  # d_z x d_t
    k /= np.maximum(np.linalg.norm(k, axis=1, keepdims=True), 1e-12)
    if n and k[j] @ d[2 * n] < 0:
        k = -k
    return ContourRays(np.stack([x, y], -1), outward, k, bias)


@dataclass
class Candidates:
    """Model nodes that may lie on a camera's silhouette outline at a pose (world frame)."""

    part: np.ndarray  # (C,)
    points: np.ndarray  # (C, 3)
    normal: np.ndarray  # (C, 3) generator normal (side) or side normal of the rim node
    cap: np.ndarray  # (C, 3) cap normal (rim nodes), zeros for side nodes
    rim: np.ndarray  # (C,) bool
    uv: np.ndarray  # (C, 2)
    key: np.ndarray | None = (
        None  # (C,) identity of the node (ring and generator side, or rim node)
    )
    usable: np.ndarray | None = (
        None  # (C,) on the predicted outline; None = all.  The others only absorb
    )
    # the samples nearest to them (ambiguous: a narrow gap, a hidden edge)

    def __len__(self) -> int:
        return len(self.part)

    def subset(self, keep: np.ndarray) -> 'Candidates':
        """Return the candidates selected by a mask or index array.

        These candidates themselves when a mask keeps all.
        """
        if keep.dtype == bool and len(keep) == len(self) and keep.all():
            return self
        return Candidates(
            self.part[keep],
            self.points[keep],
            self.normal[keep],
            self.cap[keep],
            self.rim[keep],
            self.uv[keep],
            None if self.key is None else self.key[keep],
            None if self.usable is None else self.usable[keep],
        )


def outline_candidates(
    camera: Camera,
    nodes: ModelNodes,
    rotations: np.ndarray,
    origins: np.ndarray,
    keys: np.ndarray | None = None,
) -> Candidates:
    """Every node that can be on an outline by its own shape.

    The generator points of each side ring and the rim nodes whose normal fan can face across the
    ray (no test against the other parts); only the nodes named by ``keys`` (see
    :attr:`Candidates.key`) when given.
    """
    return rig_outline_candidates(
        [camera], nodes, rotations, origins, None if keys is None else [keys]
    )[0]


def rig_outline_candidates(
    cameras: list[Camera],
    nodes: ModelNodes,
    rotations: np.ndarray,
    origins: np.ndarray,
    keys: list[np.ndarray] | None = None,
) -> list[Candidates]:
    """:func:`outline_candidates` of every camera (``keys`` per camera when given).

    Computed in one batch: the nodes of all cameras go through the same array operations, side
    nodes before rim nodes within a camera.
    """
    n_cams, n_keys = len(cameras), 2 * len(nodes)
    centres = np.array([np.asarray(c.t_world_cam, float) for c in cameras])
    centre_local = _rotate(
        rotations.transpose(0, 2, 1)[None], centres[:, None] - origins
    )  # (K, P, 3) R^T (c - o)
    # side: one node per ring and generator (the ring's nodes nearest the two generator lines,
    # moved onto them)
    if keys is None:
        idx = np.tile(nodes.side_index, n_cams)
        sign = np.tile(nodes.side_sign, n_cams)
        cam_s = np.repeat(np.arange(n_cams), len(nodes.side_index))
        rim_idx, cam_r = (
            np.tile(nodes.rim_index, n_cams),
            np.repeat(np.arange(n_cams), len(nodes.rim_index)),
        )
        rim_local, rim_n = (
            np.tile(nodes.rim_points, (n_cams, 1)),
            np.tile(nodes.rim_normals, (n_cams, 1)),
        )
    else:
        all_keys = np.concatenate(keys)
        cam_k = np.repeat(np.arange(n_cams), [len(k) for k in keys])
        side = all_keys < n_keys
        idx, sign, cam_s = (
            all_keys[side] // 2,
            np.where(all_keys[side] % 2 == 0, 1.0, -1.0),
            cam_k[side],
        )
        rim_sel, cam_r = np.searchsorted(nodes.rim_index, all_keys[~side] - n_keys), cam_k[~side]
        rim_idx, rim_local, rim_n = (
            nodes.rim_index[rim_sel],
            nodes.rim_points[rim_sel],
            nodes.rim_normals[rim_sel],
        )
    theta = _generator(nodes, centre_local[cam_s, nodes.part[idx]], idx, sign)
    ok = np.isfinite(theta)
    idx, theta, cam_s, key_side = idx[ok], theta[ok], cam_s[ok], (2 * idx + (sign < 0))[ok]
    cos, sin = np.cos(theta), np.sin(theta)
    local = np.stack([nodes.a[idx] * cos, nodes.b[idx] * sin, nodes.z[idx]], -1)
    n_local = np.stack([cos / nodes.a[idx], sin / nodes.b[idx], np.zeros_like(theta)], -1)
    n_local /= _norm(n_local)[:, None]
    # rims: nodes whose normal fan holds a direction (nearly) perpendicular to the ray
    rim_sign = nodes.rim[rim_idx]  # cap normal (0, 0, rim_sign)
    view = rim_local - centre_local[cam_r, nodes.part[rim_idx]]
    s_dot, c_dot = _dot(rim_n, view), rim_sign * view[:, 2]
    norm = _norm(view)
    keep = (
        (s_dot * c_dot <= 0)
        | (np.abs(s_dot) <= RIM_VIEW_COS * norm)
        | (np.abs(c_dot) <= RIM_VIEW_COS * norm)
    )
    # camera by camera, each camera's side nodes before its rim nodes
    cam = np.concatenate([cam_s, cam_r[keep]])
    order = np.argsort(cam, kind='stable')
    part = np.concatenate([nodes.part[idx], nodes.part[rim_idx[keep]]])[order]
    cap_sign = np.concatenate([np.zeros(len(idx)), rim_sign[keep]])[order]
    key = np.concatenate([key_side, n_keys + rim_idx[keep]])[order]
    r = rotations[part]
    points = _rotate(r, np.concatenate([local, rim_local[keep]])[order]) + origins[part]
    normal = _rotate(r, np.concatenate([n_local, rim_n[keep]])[order])
    cap = r[:, :, 2] * cap_sign[:, None]
    rim = cap_sign != 0
    ends = np.cumsum(np.bincount(cam, minlength=n_cams))
    return [
        Candidates(
            part[a:b],
            points[a:b],
            normal[a:b],
            cap[a:b],
            rim[a:b],
            c.project(points[a:b]),
            key[a:b],
        )
        for c, a, b in zip(cameras, np.concatenate(([0], ends[:-1])), ends)
    ]


def _rotate(r: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R @ v for stacks of 3x3 matrices r (..., 3, 3) and vectors v (..., 3), written out.

    Cheaper than a batched product of so small matrices.
    """
    return r[..., 0] * v[..., 0, None] + r[..., 1] * v[..., 1, None] + r[..., 2] * v[..., 2, None]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (M, 3) arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _norm(a: np.ndarray) -> np.ndarray:
    """Row-wise lengths of an (M, 3) array."""
    return np.sqrt(_dot(a, a))


def _outline_normals(
    view: np.ndarray, side: np.ndarray, cap: np.ndarray, rim: np.ndarray
) -> np.ndarray:
    """Return unit normal of the outline at each node, perpendicular to the viewing ray.

    The generator normal for side nodes, and for rim nodes the direction of their fan (side to cap)
    that is perpendicular to the ray.
    """
    v = view / _norm(view)[:, None]
    s_dot, c_dot = _dot(side, v), _dot(cap, v)
    in_fan = rim & (s_dot * c_dot <= 0)
    fan = c_dot[:, None] * side - s_dot[:, None] * cap
    fan *= np.where(_dot(fan, side + cap) < 0, -1.0, 1.0)[:, None]
    extreme = np.where((np.abs(s_dot) <= np.abs(c_dot))[:, None], side, cap)
    n = np.where(in_fan[:, None], fan, np.where(rim[:, None], extreme, side))
    n = n - _dot(n, v)[:, None] * v
    return n / np.maximum(_norm(n), 1e-12)[:, None]


def ray_part_hits(
    cameras: list[Camera],
    ray_camera: np.ndarray,
    directions: np.ndarray,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every hit of the unit rays ``directions`` (R, 3).

    Each from the centre of ``cameras[ray_camera]``, on the parts' capped elliptic cylinders, as
    (ray, part, distance) arrays.

    A ray is tested exactly only against the parts whose bounding box it meets in its camera's
    normalised image plane: a box wholly in front of the camera projects inside the bounds of its
    projected corners, so a ray outside them cannot hit the part (most rays pass far from most
    parts).
    """
    n_parts = len(lengths)
    centres = np.array([np.asarray(c.t_world_cam, float) for c in cameras])  # (K, 3)
    r_world_cam = np.array([np.asarray(c.R_world_cam, float) for c in cameras])  # (K, 3, 3)
    extents = np.concatenate([semi_axes, lengths[:, None]], axis=1)  # (P, 3)
    box = _BOX_CORNERS * extents[:, None]  # (P, 8, 3) in the part frames
    corners = np.matmul(box, rotations.transpose(0, 2, 1)) + origins[:, None]
    corners = (corners - centres[:, None, None]) @ r_world_cam[
        :, None
    ]  # (K, P, 8, 3) in the camera frames
    depth = corners[..., 2]
    in_front = np.all(depth > 1e-9, axis=2)
    plane = corners[..., :2] / np.where(in_front[..., None], depth, 1.0)[..., None]
    margin = 1e-9 * (1.0 + np.abs(plane).max(axis=2))
    low = np.where(in_front[..., None], plane.min(axis=2) - margin, -np.inf)  # (K, P, 2)
    high = np.where(in_front[..., None], plane.max(axis=2) + margin, np.inf)
    d_cam = _rotate(r_world_cam.transpose(0, 2, 1)[ray_camera], directions)
    ahead = d_cam[:, 2] > 0
    ray_plane = (
        np.where(ahead[:, None], d_cam[:, :2], 0.0) / np.where(ahead, d_cam[:, 2], 1.0)[:, None]
    )
    low, high = low[ray_camera], high[ray_camera]  # (R, P, 2)
    near = (
        (ray_plane[:, None, 0] >= low[..., 0])
        & (ray_plane[:, None, 0] <= high[..., 0])
        & (ray_plane[:, None, 1] >= low[..., 1])
        & (ray_plane[:, None, 1] <= high[..., 1])
    )
    near &= (
        ahead[:, None] | ~in_front[ray_camera]
    )  # a ray not going ahead cannot meet a box in front
    pair = np.flatnonzero(near)
    ray, part = np.divmod(pair, n_parts)
    # the exact test: rays and cylinders in the part frames, scaled so the cross-section is the
    # unit circle
    o = _rotate(
        rotations.transpose(0, 2, 1)[None], centres[:, None] - origins
    )  # (K, P, 3) ray origins
    o = o[ray_camera[ray], part]
    d = (directions @ rotations.transpose(1, 0, 2).reshape(3, -1)).reshape(
        -1, 3
    )  # (R * P, 3) directions
    a, b = semi_axes[part, 0], semi_axes[part, 1]
    ox, oy, oz, length = o[:, 0] / a, o[:, 1] / b, o[:, 2], lengths[part]
    dx, dy, dz = d[pair, 0] / a, d[pair, 1] / b, d[pair, 2]
    qa = dx * dx + dy * dy
    qb = 2.0 * (ox * dx + oy * dy)
    qc = ox * ox + oy * oy - 1.0
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(invalid='ignore', divide='ignore'):
        s_side = (-qb - np.sqrt(disc)) / (2.0 * qa)
        z_side = oz + s_side * dz
        best = np.where(
            (disc >= 0) & (s_side > 0) & (z_side >= 0) & (z_side <= length), s_side, np.inf
        )
        for z_cap in (0.0, length):
            s_cap = (z_cap - oz) / dz
            x = ox + s_cap * dx
            y = oy + s_cap * dy
            best = np.where((s_cap > 0) & (x * x + y * y <= 1.0) & (s_cap < best), s_cap, best)
    hit = np.isfinite(best)
    return ray[hit], part[hit], best[hit]


def on_outline(
    camera: Camera,
    cand: Candidates,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    probe_px: float = OUTLINE_PROBE_PX,
) -> np.ndarray:
    """(C,) True where a candidate is on the predicted body's occluding contour.

    Nothing hides it, and the ray ``probe_px`` outside it across the outline meets no part (it is
    not inside another part's silhouette).
    """
    return rig_on_outline([camera], [cand], rotations, origins, semi_axes, lengths, probe_px)[0]


def rig_on_outline(
    cameras: list[Camera],
    cands: list[Candidates],
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    probe_px: float = OUTLINE_PROBE_PX,
) -> list[np.ndarray]:
    """:func:`on_outline` of every camera's candidates, all tested in one batch of rays."""
    counts = [len(c) for c in cands]
    node_camera = np.repeat(np.arange(len(cameras)), counts)
    points = np.concatenate([c.points for c in cands])
    normal, cap = np.concatenate([c.normal for c in cands]), np.concatenate([c.cap for c in cands])
    centre = np.array([np.asarray(c.t_world_cam, float) for c in cameras])[node_camera]
    focal = np.array([float(c.K[0, 0]) for c in cameras])[node_camera]
    view = points - centre
    dist = _norm(view)
    outline = _outline_normals(view, normal, cap, np.concatenate([c.rim for c in cands]))
    probe = (
        view + (probe_px * dist / focal)[:, None] * outline
    )  # probe_px in the image, to first order
    dirs = np.concatenate([view / dist[:, None], probe / _norm(probe)[:, None]])
    ray, _, hit = ray_part_hits(
        cameras,
        np.concatenate([node_camera, node_camera]),
        dirs,
        rotations,
        origins,
        semi_axes,
        lengths,
    )
    n = len(points)
    to_node = ray < n
    blocked = np.zeros(2 * n, bool)
    blocked[ray[to_node][hit[to_node] < dist[ray[to_node]] - RAY_TOLERANCE_M]] = True  # hidden
    blocked[ray[~to_node]] = True  # covered
    usable = (
        ~blocked[:n]
        & ~blocked[n:]
        & np.all(np.isfinite(np.concatenate([c.uv for c in cands])), axis=1)
    )
    return np.split(usable, np.cumsum(counts)[:-1])


def _generator(
    nodes: ModelNodes, centre_local: np.ndarray, idx: np.ndarray, sign: np.ndarray
) -> np.ndarray:
    """Return generator angle of the rings starting at idx.

    On the side ``sign`` (+1: phi + arccos, -1: phi - arccos), for the camera centre in each ring's
    part frame; NaN when the centre is inside the cylinder.
    """
    ux, uy = centre_local[:, 0] / nodes.a[idx], centre_local[:, 1] / nodes.b[idx]
    rho = np.hypot(ux, uy)
    with np.errstate(invalid='ignore', divide='ignore'):
        half = np.where(rho > 1.0, np.arccos(np.clip(1.0 / rho, -1.0, 1.0)), np.nan)
    return np.arctan2(uy, ux) + sign * half


@dataclass
class Matches:
    """Contour samples tied to candidate nodes (Step 3)."""

    sample: np.ndarray  # (N,) index into the camera's contour table
    node: np.ndarray  # (N,) index into the candidates
    distance: np.ndarray  # (N,) pixels between the sample and the node's projection


def _alignment(
    rays: ContourRays, candidates: Candidates, sample: np.ndarray, node: np.ndarray
) -> np.ndarray:
    """N . k_z of each (sample, node) pair, over the rim's normal fan for rim nodes.

    Eq. 13's left side.
    """
    kz = rays.k[sample]
    align = _dot(candidates.normal[node], kz)
    rim = np.flatnonzero(candidates.rim[node])
    if len(rim):  # the fan only for the rim nodes' pairs (the same values, fewer gathers)
        align[rim] = fan_alignment(
            candidates.normal[node[rim]], candidates.cap[node[rim]], kz[rim]
        )
    return align


def _nearest_compatible(
    tree: cKDTree, queries: np.ndarray, k: int, gate_px: float, compatible
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of ``queries`` with a target passing eq. 13 among their ``k`` nearest, and the nearest.

    Targets are looked up in ``tree`` within ``gate_px``; the result is (rows, target index,
    distance) of the nearest passing target of each such row.  ``compatible(rows, targets)`` is
    eq. 13 for those pairs.

    The nearest target alone settles almost every row (it is compatible, or nothing is within the
    gate), so the ``k`` nearest are only looked up for the rows whose nearest failed or ties with
    the second (targets at the same pixel, then taken in the tree's order of the ``k``): the answer
    of examining all ``k`` for every row.
    """
    if k < 2:
        dist, idx = tree.query(queries, k=1, distance_upper_bound=gate_px)
        rows = np.flatnonzero(idx < tree.n)
        ok = compatible(rows, idx[rows])
        return rows[ok], idx[rows[ok]], dist[rows[ok]]
    # nearest targets are mostly far inside the gate: a search within a quarter of it visits less
    # of the tree,
    # and the rows with nothing that near are searched again within the whole gate (the same two
    # neighbours)
    dist, idx = tree.query(queries, k=2, distance_upper_bound=0.25 * gate_px)
    far = np.flatnonzero(idx[:, 0] == tree.n)
    if len(far):
        dist[far], idx[far] = tree.query(queries[far], k=2, distance_upper_bound=gate_px)
    rows = np.flatnonzero(idx[:, 0] < tree.n)
    ok = compatible(rows, idx[rows, 0]) & (dist[rows, 0] < dist[rows, 1])
    sel, target, d = rows[ok], idx[rows[ok], 0], dist[rows[ok], 0]
    retry = rows[~ok]
    if not len(retry):
        return sel, target, d
    dist, idx = tree.query(queries[retry], k=k, distance_upper_bound=gate_px)
    pair_row, pair_col = np.nonzero(idx < tree.n)
    passed = np.zeros(idx.shape, bool)
    passed[pair_row, pair_col] = compatible(retry[pair_row], idx[pair_row, pair_col])
    has = passed.any(axis=1)
    first = np.argmax(passed, axis=1)[has]
    rows = np.concatenate([sel, retry[has]])
    order = np.argsort(rows, kind='stable')
    return (
        rows[order],
        np.concatenate([target, idx[has, first]])[order],
        np.concatenate([d, dist[has, first]])[order],
    )


def assign_forces(
    rays: ContourRays,
    candidates: Candidates,
    epsilon: np.ndarray,
    gate_px: float,
    symmetric: bool = False,
) -> Matches:
    """Match each sample to the nearest projected candidate passing eq. 13 within ``gate_px``.

    Steps 2-3; with ``symmetric`` also each candidate to its nearest eq. 13-compatible sample
    (pairs counted once).
    """
    empty = Matches(np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    if not len(candidates) or not len(rays.uv):
        return empty
    eps = epsilon[candidates.part]
    sample, node, d = _nearest_compatible(
        cKDTree(candidates.uv),
        rays.uv,
        min(NEIGHBOURS, len(candidates)),
        gate_px,
        lambda s, c: _alignment(rays, candidates, s, c) >= eps[c],
    )  # eq. 13
    if candidates.usable is not None:  # nearest node not on the outline: ambiguous, dropped
        ok = candidates.usable[node]
        sample, node, d = sample[ok], node[ok], d[ok]
    if not symmetric:
        return Matches(sample, node, d)
    pullers = (
        np.arange(len(candidates))
        if candidates.usable is None
        else np.flatnonzero(candidates.usable)
    )
    node_b, sample_b, d_b = _nearest_compatible(
        rays.tree,
        candidates.uv[pullers],
        min(NEIGHBOURS, len(rays.uv)),
        gate_px,
        lambda c, s: _alignment(rays, candidates, s, pullers[c]) >= eps[pullers[c]],
    )  # eq. 13
    node_b = pullers[node_b]
    pair = np.concatenate([sample * len(candidates) + node, sample_b * len(candidates) + node_b])
    _, first = np.unique(pair, return_index=True)
    return Matches(
        np.concatenate([sample, sample_b])[first],
        np.concatenate([node, node_b])[first],
        np.concatenate([d, d_b])[first],
    )
