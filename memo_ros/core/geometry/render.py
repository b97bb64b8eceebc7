"""Ray casting of the body's elliptic cylinders into label, depth and normal images.

Every pixel's ray is intersected exactly with each part's elliptic cylinder
(side and end caps); the nearest hit wins.  Only the pixels inside a part's
projected bounding box are tested, so the cost follows the body's image size,
not the image's.  The selector uses it for visibility (Kakadiaris §4, VI =
visible area / unoccluded area) and the simulator for images.

The simulator can also image a body whose shape is not the tracker's: ``rounded`` parts are
elliptic capsules (the cylinder's cross-section, half-ellipsoid ends) that reach over their
joints, as a real person's limbs round off and merge there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from memo_ros.core.geometry.body import PART_NAMES
from memo_ros.core.geometry.camera import Camera

BACKGROUND = 0  # label of pixels that see no part; part i has label i + 1
NEAR = 1e-6
MAX_COORDINATE_M = 1e4  # a part farther from the world origin (an absurd pose) is not rendered
MAX_PIXELS = 1e7  # projected corners are clipped to this many pixels before becoming box bounds
SHAPES = ('cylinders', 'rounded')  # the tracker's elliptic cylinders; elliptic capsules
CAP_SHARE = 0.3  # a rounded part's end is at most this share of its length deep
# a rounded limb is this much wider than its cylinder at the proximal joint, narrower at the distal
LIMB_TAPER = {'upper_arm': 0.15, 'forearm': 0.12, 'thigh': 0.18, 'shank': 0.15}


@dataclass
class Rendering:
    """What a camera sees of the body.

    Labels (part index + 1, 0 = none), depth along the optical axis (inf = none).
    """

    label: np.ndarray  # (H, W) uint8
    depth: np.ndarray  # (H, W) float32, metres along the optical z axis
    normal: (
        np.ndarray | None
    )  # (H, W, 3) float32 unit surface normals in the camera frame, or None
    unoccluded_area: np.ndarray  # (P,) pixels each part covers when occlusions are ignored

    def visible_area(self, n_parts: int) -> np.ndarray:
        """Pixels where each part is the nearest surface (P,)."""
        return np.bincount(self.label.ravel(), minlength=n_parts + 1)[1 : n_parts + 1]


def render(
    camera: Camera,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    scale: float = 1.0,
    parts: np.ndarray | None = None,
    normals: bool = False,
    shape: str = 'cylinders',
) -> Rendering:
    """Render parts posed by (rotations (P,3,3), origins (P,3)) into ``camera``.

    The image has ``scale`` times the camera's resolution; ``shape`` is one of :data:`SHAPES`.
    """
    if shape not in SHAPES:
        raise ValueError(f'unknown shape {shape!r}; known: {", ".join(SHAPES)}')
    ends, box_axes = None, semi_axes
    if shape == 'rounded':
        caps, taper, origins, lengths = _capsule_spans(rotations, origins, semi_axes, lengths)
        ends = (caps, taper)
        box_axes = semi_axes * (1.0 + taper[:, None])  # the boxes hold the wider end
    view = camera.scaled(scale) if scale != 1.0 else camera
    rays = camera.pixel_grid_rays(scale)  # (H, W, 3) world unit directions
    height, width = rays.shape[:2]
    centre = np.asarray(camera.t_world_cam, float)
    optical_z = np.asarray(camera.R_world_cam, float)[:, 2]
    label = np.zeros((height, width), np.uint8)
    depth = np.full((height, width), np.inf, np.float32)
    normal_img = np.zeros((height, width, 3), np.float32) if normals else None
    n_parts = len(lengths)
    area = np.zeros(n_parts, np.int64)
    selected = range(n_parts) if parts is None else parts
    boxes = np.stack(_projected_boxes(view, rotations, origins, box_axes, lengths), 1).tolist()
    _cast_boxes(
        rays,
        centre,
        optical_z,
        np.asarray(camera.R_world_cam, float),
        rotations,
        origins,
        semi_axes,
        lengths,
        [(i, *boxes[i]) for i in selected],
        label,
        depth,
        normal_img,
        area,
        ends,
    )
    return Rendering(label, depth, normal_img, area)


def _capsule_spans(
    rotations: np.ndarray, origins: np.ndarray, semi_axes: np.ndarray, lengths: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return each rounded part's end depth and taper (P,), and its whole span's origins, lengths.

    An end is as deep as the part's smaller semi-axis (at most CAP_SHARE of its length) and the
    capsule reaches half that depth past each joint, so neighbouring parts merge.  The body's
    limbs (:data:`PART_NAMES`) taper by :data:`LIMB_TAPER`; other parts, or parts not named
    so, keep their cross-section.
    """
    caps = np.minimum(semi_axes.min(axis=1), CAP_SHARE * lengths)
    start = origins - 0.5 * caps[:, None] * rotations[:, :, 2]
    taper = np.zeros(len(lengths))
    if len(lengths) == len(PART_NAMES):
        taper[:] = [LIMB_TAPER.get(name.rsplit('_', 1)[0], 0.0) for name in PART_NAMES]
    return caps, taper, start, lengths + caps


def _cast_boxes(
    rays: np.ndarray,
    centre: np.ndarray,
    optical_z: np.ndarray,
    R_world_cam: np.ndarray,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    boxes: list,
    label: np.ndarray,
    depth: np.ndarray,
    normal_img: np.ndarray | None,
    area: np.ndarray,
    ends: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """Cast the parts' boxes (i, u0, u1, v0, v1), in order, into label, depth (and normals).

    The ray-cylinder test (:func:`_hit_local`, elementwise, ~50 numpy calls) runs once on every
    box's pixels instead of once per part, where the calls on a thousand pixels each cost more
    than their arithmetic; each part's rays are turned into its frame by the part's own product,
    and the hits are then written part after part where nearer than the depth so far, exactly as
    before.
    """
    cast, o, d, a, b, length, cap, taper = [], [], [], [], [], [], [], []
    for i, u0, u1, v0, v1 in boxes:
        if u0 >= u1 or v0 >= v1:
            continue
        block = rays[v0:v1, u0:u1].reshape(-1, 3)
        n = len(block)
        cast.append((i, u0, u1, v0, v1, block))
        o.append(np.broadcast_to(rotations[i].T @ (centre - origins[i]), (n, 3)))
        d.append(block @ rotations[i])
        a.append(np.full(n, semi_axes[i][0]))
        b.append(np.full(n, semi_axes[i][1]))
        length.append(np.full(n, lengths[i]))
        if ends is not None:
            cap.append(np.full(n, ends[0][i]))
            taper.append(np.full(n, ends[1][i]))
    if not cast:
        return
    cat = np.concatenate
    want_normals = normal_img is not None
    if ends is None:
        dist_all, n_all = _hit_local(cat(o), cat(d), cat(a), cat(b), cat(length), want_normals)
    else:
        dist_all, n_all = _hit_capsule(
            cat(o), cat(d), cat(a), cat(b), cat(length), cat(cap), cat(taper), want_normals
        )
    end = 0
    for i, u0, u1, v0, v1, block in cast:
        begin, end = end, end + len(block)
        dist = dist_all[begin:end]
        hit = np.isfinite(dist)
        area[i] = int(hit.sum())
        if not area[i]:
            continue
        z = (dist * (block @ optical_z)).astype(np.float32)
        region = depth[v0:v1, u0:u1].reshape(-1)
        nearer = hit & (z < region)
        region[nearer] = z[nearer]
        depth[v0:v1, u0:u1] = region.reshape(v1 - v0, u1 - u0)
        labels = label[v0:v1, u0:u1].reshape(-1)
        labels[nearer] = i + 1
        label[v0:v1, u0:u1] = labels.reshape(v1 - v0, u1 - u0)
        if normal_img is not None and n_all is not None:
            n_cam = n_all[begin:end][nearer] @ (R_world_cam.T @ rotations[i]).T
            block_n = normal_img[v0:v1, u0:u1].reshape(-1, 3)
            block_n[nearer] = n_cam
            normal_img[v0:v1, u0:u1] = block_n.reshape(v1 - v0, u1 - u0, 3)


def _hit_local(o: np.ndarray, d: np.ndarray, a, b, length, want_normals: bool):
    """Ray-cylinder hits in part frames.

    Origins o (3,) or (N, 3), directions d (N, 3); a, b, length scalar or (N,).
    """
    # side: (x/a)^2 + (y/b)^2 = 1 with 0 <= z <= length
    ox, oy = o[..., 0] / a, o[..., 1] / b
    dx, dy = d[:, 0] / a, d[:, 1] / b
    qa = dx * dx + dy * dy
    qb = 2.0 * (ox * dx + oy * dy)
    qc = ox * ox + oy * oy - 1.0
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(invalid='ignore', divide='ignore'):
        root = np.sqrt(disc)
        s_side = (-qb - root) / (2.0 * qa)
        s_far = (-qb + root) / (2.0 * qa)
    s_side = np.where(s_side > NEAR, s_side, s_far)  # camera inside the infinite cylinder
    z_side = o[..., 2] + s_side * d[:, 2]
    side_ok = (disc >= 0) & (s_side > NEAR) & (z_side >= 0.0) & (z_side <= length)
    best = np.where(side_ok, s_side, np.inf)
    cap_id = np.zeros(len(d), np.int8)
    for k, z_cap in ((1, 0.0), (2, length)):
        with np.errstate(invalid='ignore', divide='ignore'):
            s_cap = (z_cap - o[..., 2]) / d[:, 2]
        x = (o[..., 0] + s_cap * d[:, 0]) / a
        y = (o[..., 1] + s_cap * d[:, 1]) / b
        ok = (s_cap > NEAR) & (x * x + y * y <= 1.0) & (s_cap < best)
        best = np.where(ok, s_cap, best)
        cap_id = np.where(ok, k, cap_id)
    if not want_normals:
        return best, None
    points = o + np.where(np.isfinite(best), best, 0.0)[:, None] * d
    n = np.stack([points[:, 0] / (a * a), points[:, 1] / (b * b), np.zeros(len(d))], -1)
    n[cap_id == 1] = (0.0, 0.0, -1.0)
    n[cap_id == 2] = (0.0, 0.0, 1.0)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return best, n


def _hit_capsule(o: np.ndarray, d: np.ndarray, a, b, length, cap, taper, want_normals: bool):
    """Ray hits on tapered elliptic capsules in part frames: z in [0, length], ends ``cap`` deep.

    The union of a side (z in [cap, length - cap]; its cross-section the ellipse (a, b) scaled by
    1 + taper at z = cap/2, the joint, falling linearly to 1 - taper one part's length further)
    and two ellipsoids centred at z = cap and z = length - cap, each as wide as the side there
    and ``cap`` deep.  The rays start outside, so the nearest hit on the union is the nearest of
    its pieces'.  Arguments as :func:`_hit_local`'s, ``cap`` and ``taper`` (N,).
    """
    o = np.broadcast_to(o, d.shape)
    ox, oy = o[:, 0] / a, o[:, 1] / b
    dx, dy = d[:, 0] / a, d[:, 1] / b
    slope = -2.0 * taper / np.maximum(length - cap, 1e-12)  # d(scale)/dz; the part is length - cap

    def scale_at(z):  # the cross-section's scale at z (1 + taper at the joint, z = cap / 2)
        return 1.0 + taper + slope * (z - 0.5 * cap)

    w0 = scale_at(o[:, 2])  # where the ray starts
    w1 = slope * d[:, 2]
    qa = dx * dx + dy * dy - w1 * w1
    qb = 2.0 * (ox * dx + oy * dy - w0 * w1)
    qc = ox * ox + oy * oy - w0 * w0
    disc = qb * qb - 4.0 * qa * qc
    best = np.full(len(d), np.inf)
    with np.errstate(invalid='ignore', divide='ignore'):
        root = np.sqrt(disc)
        for s_side in ((-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa)):
            z_side = o[:, 2] + s_side * d[:, 2]
            ok = (disc >= 0) & (s_side > NEAR) & (z_side >= cap) & (z_side <= length - cap)
            best = np.where(ok & (s_side < best), s_side, best)
    piece = np.zeros(len(d), np.int8)  # 0 side, 1 lower end, 2 upper end
    for k, centre in ((1, cap), (2, length - cap)):
        width = scale_at(centre)
        ex, ey = ox / width, oy / width
        fx, fy = dx / width, dy / width
        oz, dz = (o[:, 2] - centre) / cap, d[:, 2] / cap
        ea = fx * fx + fy * fy + dz * dz
        eb = 2.0 * (ex * fx + ey * fy + oz * dz)
        ec = ex * ex + ey * ey + oz * oz - 1.0
        e_disc = eb * eb - 4.0 * ea * ec
        with np.errstate(invalid='ignore', divide='ignore'):
            s_end = (-eb - np.sqrt(e_disc)) / (2.0 * ea)
        ok = (e_disc >= 0) & (s_end > NEAR) & (s_end < best)
        best = np.where(ok, s_end, best)
        piece = np.where(ok, k, piece)
    if not want_normals:
        return best, None
    points = o + np.where(np.isfinite(best), best, 0.0)[:, None] * d
    z = points[:, 2]
    centre_z = np.where(piece == 1, cap, length - cap)
    scale = scale_at(np.where(piece == 0, z, centre_z))
    along = np.where(
        piece == 0,
        -scale * slope,  # the cone's gradient along z, (x/a)^2 + (y/b)^2 - s(z)^2 halved
        (z - centre_z) / np.maximum(cap, 1e-12) ** 2,
    )
    lateral = np.where(piece == 0, 1.0, 1.0 / np.maximum(scale, 1e-12) ** 2)
    n = np.stack([points[:, 0] / (a * a) * lateral, points[:, 1] / (b * b) * lateral, along], -1)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return best, n


def render_labels(
    camera: Camera,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    scale: float = 1.0,
    view: Camera | None = None,
) -> Rendering:
    """Label and depth images like :func:`render` (no normals).

    Every part's box cast in one vectorised batch.

    The same exact ray-cylinder test over the same projected boxes, so labels, depths and
    unoccluded areas equal :func:`render`'s; it saves the per-part overhead, which dominates at
    reduced resolution.  ``view`` is ``camera.scaled(scale)`` when the caller keeps one.
    """
    view = view if view is not None else (camera.scaled(scale) if scale != 1.0 else camera)
    rays = camera.pixel_grid_rays(scale).reshape(-1, 3)
    height, width = view.height, view.width
    n_parts = len(lengths)
    u0, u1, v0, v1 = _projected_boxes(view, rotations, origins, semi_axes, lengths)
    box_w, box_h = np.maximum(u1 - u0, 0), np.maximum(v1 - v0, 0)
    sizes = box_w * box_h
    part = np.repeat(np.arange(n_parts), sizes)  # one entry per (part, pixel in its box)
    k = np.arange(len(part)) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    w = np.maximum(box_w, 1)[part]
    pixel = (v0[part] + k // w) * width + u0[part] + k % w
    centre = np.asarray(camera.t_world_cam, float)
    o_local = np.einsum('pji,pj->pi', rotations, centre - origins)  # R^T (c - o) per part
    directions = rays[pixel]
    d_local = np.einsum('nj,nji->ni', directions, rotations[part])
    dist, _ = _hit_local(
        o_local[part], d_local, semi_axes[part, 0], semi_axes[part, 1], lengths[part], False
    )
    hit = np.isfinite(dist)
    area = np.bincount(part[hit], minlength=n_parts).astype(np.int64)
    pixel, part = pixel[hit], part[hit]
    z = (dist[hit] * (directions[hit] @ np.asarray(camera.R_world_cam, float)[:, 2])).astype(
        np.float32
    )
    order = np.lexsort((z, pixel))  # per pixel, nearest first
    pixel, part, z = pixel[order], part[order], z[order]
    first = np.ones(len(pixel), bool)
    first[1:] = pixel[1:] != pixel[:-1]
    label = np.zeros(height * width, np.uint8)
    depth = np.full(height * width, np.inf, np.float32)
    label[pixel[first]] = part[first] + 1
    depth[pixel[first]] = z[first]
    return Rendering(label.reshape(height, width), depth.reshape(height, width), None, area)


def _projected_boxes(
    view: Camera,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    margin: int = 2,
) -> tuple[np.ndarray, ...]:
    """Pixel bounds (u0, u1, v0, v1), each (P,), of every part's projection; empty: u0 >= u1.

    The box of the projected corners of the part's bounding box, ``margin`` pixels wider; the
    whole image when a corner is behind the camera, empty for a part posed absurdly.
    """
    signs = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (0.0, 1.0)])
    scale = np.concatenate([semi_axes, lengths[:, None]], axis=1)  # (P, 3)
    corners = signs[None] * scale[:, None]  # (P, 8, 3)
    sane = _sane_parts(rotations, origins)
    world = origins[:, None] + np.einsum('pij,pcj->pci', rotations, corners)
    uv = view.project(np.where(sane[:, None, None], world, 0.0))
    finite = np.all(np.isfinite(uv), axis=(1, 2))
    with np.errstate(invalid='ignore'):  # pixels clipped before they become integers
        lo = np.clip(np.nan_to_num(uv.min(axis=1)), -MAX_PIXELS, MAX_PIXELS)
        hi = np.clip(np.nan_to_num(uv.max(axis=1)), -MAX_PIXELS, MAX_PIXELS)
    u0 = np.where(finite, np.maximum(np.floor(lo[:, 0]).astype(int) - margin, 0), 0)
    u1 = np.where(
        finite, np.minimum(np.ceil(hi[:, 0]).astype(int) + margin + 1, view.width), view.width
    )
    v0 = np.where(finite, np.maximum(np.floor(lo[:, 1]).astype(int) - margin, 0), 0)
    v1 = np.where(
        finite, np.minimum(np.ceil(hi[:, 1]).astype(int) + margin + 1, view.height), view.height
    )
    u1 = np.where(sane, u1, 0)  # a part posed absurdly is not cast at all
    return u0, u1, v0, v1


def _sane_parts(rotations: np.ndarray, origins: np.ndarray) -> np.ndarray:
    """Return which parts (P,) are posed finitely within MAX_COORDINATE_M of the world origin."""
    with np.errstate(invalid='ignore'):
        return (
            np.all(np.isfinite(rotations), axis=(1, 2))
            & np.all(np.isfinite(origins), axis=1)
            & np.all(np.abs(origins) <= MAX_COORDINATE_M, axis=1)
        )


def render_body(
    camera: Camera, body, q: np.ndarray, scale: float = 1.0, normals: bool = False
) -> Rendering:
    """Provide, for convenience: forward kinematics of ``body`` at ``q`` then :func:`render`."""
    rotations, origins = body.forward_kinematics(q)
    return render(
        camera, rotations, origins, body.semi_axes, body.lengths, scale=scale, normals=normals
    )
