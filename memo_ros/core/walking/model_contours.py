"""Visible model contours (Rohr §3.2, §4.3).

The straight outline lines of the 14 cylinders in one pose.

Each elliptic cylinder contributes its two silhouette generators (the surface lines where the
viewing ray from the camera centre grazes the side, found exactly: with the camera centre ``o`` in
the part frame, generator angle theta satisfies ``(o_x / a) cos theta + (o_y / b) sin theta = 1``)
and the chords closing its two ends.  Hidden contours are removed with the renderer's label image:
a sample of a line is visible where the pixel just inside it shows this part and the pixel just
outside does not (so the rendered image has an edge there).  Visible runs become the model
contours, kept as 3D segments so that a shifted model can be projected exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import Rendering, render

SIDE, CAP = 0, 1


@dataclass
class ModelContours:
    """Visible contour segments: 3D endpoints in world, owning part, kind (SIDE or CAP)."""

    start: np.ndarray  # (S, 3)
    end: np.ndarray  # (S, 3)
    part: np.ndarray  # (S,) part index
    kind: np.ndarray  # (S,) SIDE or CAP

    def __len__(self) -> int:
        return len(self.part)

    def shifted(self, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Endpoints moved by world ``offsets`` (N, 3): (N, S, 3) each."""
        offsets = np.asarray(offsets, float)[:, None, :]
        return self.start[None] + offsets, self.end[None] + offsets

    def project(
        self, camera: Camera, offsets: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pixel endpoints (N, S, 2) of the contours moved by ``offsets`` (N, 3).

        Default: not moved, N = 1.
        """
        a, b = self.shifted(np.zeros((1, 3)) if offsets is None else offsets)
        return camera.project(a), camera.project(b)


def outline_segments(
    camera: Camera,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All candidate outline lines: starts, ends (P*4, 3) in world, parts (P*4,), kinds (P*4,).

    Per part: the two silhouette generators, then the chords of the z = 0 and z = length ends. A
    part whose cross-section contains the camera centre's foot point has no generators (zero-length
    lines).
    """
    n = len(lengths)
    o = np.einsum(
        'pji,pj->pi', rotations, camera.centre - origins
    )  # camera centre in each part frame
    a, b = semi_axes[:, 0], semi_axes[:, 1]
    ox, oy = o[:, 0] / a, o[:, 1] / b
    rho = np.hypot(ox, oy)
    phi = np.arctan2(oy, ox)
    spread = np.arccos(np.clip(1.0 / np.maximum(rho, 1.0), -1.0, 1.0))
    theta = np.stack([phi - spread, phi + spread], 1)  # (P, 2) generator angles
    ring = np.stack(
        [a[:, None] * np.cos(theta), b[:, None] * np.sin(theta)], -1
    )  # (P, 2, 2) in x, y
    low = np.concatenate([ring, np.zeros((n, 2, 1))], -1)  # (P, 2, 3) at z = 0
    high = low.copy()
    high[..., 2] = lengths[:, None]
    local_start = np.concatenate([low, low[:, :1], high[:, :1]], 1)  # gen 1, gen 2, cap 0, cap L
    local_end = np.concatenate([high, low[:, 1:], high[:, 1:]], 1)

    def to_world(p: np.ndarray) -> np.ndarray:
        return np.einsum('pij,pkj->pki', rotations, p) + origins[:, None, :]

    starts, ends = to_world(local_start), to_world(local_end)
    parts = np.repeat(np.arange(n), 4)
    kinds = np.tile([SIDE, SIDE, CAP, CAP], n)
    return starts.reshape(-1, 3), ends.reshape(-1, 3), parts, kinds


def visible_contours(
    camera: Camera,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    rendering: Rendering | None = None,
    step: float = 1.0,
    inset: float = 1.0,
    min_length: float = 3.0,
) -> tuple[ModelContours, Rendering]:
    """Visible runs (at least ``min_length`` px) of the outline lines.

    Hidden ones removed by the label image.
    """
    if rendering is None:
        rendering = render(camera, rotations, origins, semi_axes, lengths)
    label = rendering.label
    starts, ends, parts, kinds = outline_segments(camera, rotations, origins, semi_axes, lengths)
    a, b = camera.project(starts), camera.project(ends)
    length = np.linalg.norm(b - a, axis=1)
    ok = np.isfinite(length) & (length >= min_length)
    starts, ends, parts, kinds, a, b, length = (
        v[ok] for v in (starts, ends, parts, kinds, a, b, length)
    )
    if not len(parts):
        empty = np.zeros((0, 3))
        return ModelContours(empty, empty, np.zeros(0, int), np.zeros(0, int)), rendering
    # inward normal of each line: towards the projection of its part's centre
    centres = origins + rotations[:, :, 2] * (lengths[:, None] / 2.0)
    centre_px = camera.project(centres)[parts]
    direction = (b - a) / length[:, None]
    normal = np.stack([-direction[:, 1], direction[:, 0]], 1)
    side = np.sign(np.sum((centre_px - (a + b) / 2.0) * normal, axis=1))
    normal *= np.where(side == 0, 1.0, side)[:, None]
    # samples along the 3D line, projected (exact under perspective), up to ``step`` px apart
    n_samples = int(np.ceil(length.max() / step)) + 1
    count = np.minimum(np.ceil(length / step).astype(int) + 1, n_samples)
    used = np.arange(n_samples)[None] < count[:, None]
    t_used = (np.arange(n_samples)[None] + 0.5) / count[:, None]  # each line's own even sampling
    pts = camera.project(
        starts[:, None] + np.minimum(t_used, 1.0)[..., None] * (ends - starts)[:, None]
    )
    inside = _labels(label, pts + inset * normal[:, None])
    outside = _labels(label, pts - inset * normal[:, None])
    visible = used & (inside == parts[:, None] + 1) & (outside != parts[:, None] + 1)
    # runs of visible samples -> sub-segments [t0, t1] of the 3D line
    padded = np.pad(visible, ((0, 0), (1, 1))).astype(np.int8)
    change = np.diff(padded, axis=1)
    rows_on, cols_on = np.nonzero(change == 1)
    rows_off, cols_off = np.nonzero(change == -1)  # same order: row-major
    half = 0.5 / count[rows_on]
    t0 = np.clip(t_used[rows_on, cols_on] - half, 0.0, 1.0)
    t1 = np.clip(t_used[rows_off, cols_off - 1] + half, 0.0, 1.0)
    run_px = (t1 - t0) * length[rows_on]
    keep = run_px >= min_length
    rows, t0, t1 = rows_on[keep], t0[keep], t1[keep]
    seg = ends[rows] - starts[rows]
    contours = ModelContours(
        starts[rows] + t0[:, None] * seg,
        starts[rows] + t1[:, None] * seg,
        parts[rows],
        kinds[rows],
    )
    return contours, rendering


def _labels(label: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Label image values at pixel positions (..., 2), nearest pixel; -1 outside or at NaN."""
    h, w = label.shape
    finite = np.isfinite(pts).all(-1)
    u = np.where(finite, np.rint(np.nan_to_num(pts[..., 0])), -1).astype(np.int64)
    v = np.where(finite, np.rint(np.nan_to_num(pts[..., 1])), -1).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.full(pts.shape[:-1], -1, np.int64)
    out[inside] = label[v[inside], u[inside]]
    return out
