"""Rohr §4.3: similarity of model contours and grey-value edge lines (eq. 7-11).

For each visible model contour i (image segment of length l_Mi) a search
window is the rectangle along it of half-width r_i = c_r l_Mi.  Every edge
line is cut to the window (Liang-Barsky clipping); of the cut piece, l_i is its
projection onto the model line (<= l_Mi), d_i the distance of its midpoint
from the model line and dphi_i the angle between the lines, and

    s_i = l_i exp(-1/2 k_i^T Sigma_i^-1 k_i),  k_i = (l_Mi - l_i, d_i, dphi_i)   (eq. 7, 8)

with sigma_li = c_l l_Mi, sigma_di = c_d c_r l_Mi and a constant sigma_dphi.
The best edge per window counts; the overall similarity is

    s(p) = sum_i w_Gi w_Ki s_i / sum_i l_Mi                                     (eq. 11)

(w_V, the velocity weight, is not used: no velocity field here).  Everything is
evaluated at once for N shifted copies of the same contours (a grid search).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SimilarityParams:
    """The constants of eq. 7-11."""

    c_l: float = 0.4  # sigma_l = c_l l_M
    c_d: float = 0.5  # sigma_d = c_d r, r = c_r l_M
    c_r: float = 0.2  # window half-width r = c_r l_M
    sigma_phi: float = 0.25  # rad
    min_window: float = 2.0  # smallest window half-width r, pixels (short contours)
    gradient_weight: bool = (
        False  # w_G: weight by the edge's gradient magnitude (normalised to its mean)
    )


def candidate_edges(
    a: np.ndarray, b: np.ndarray, edges: np.ndarray, margin: float, params: SimilarityParams
) -> tuple[np.ndarray, np.ndarray]:
    """(contour, edge) pairs worth scoring for contours a, b (S, 2) moved by up to ``margin`` px.

    The edge reaches the grown window and its angle is within 3 sigma_phi. Sorted by contour.
    """
    S, E = len(a), len(edges)
    if S == 0 or E == 0:
        return np.zeros(0, int), np.zeros(0, int)
    d = b - a
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-9)[:, None]
    r = np.maximum(params.c_r * length, params.min_window) + margin
    ax, ay, ux, uy = a[:, 0:1], a[:, 1:2], u[:, 0:1], u[:, 1:2]  # (S, 1)
    x1, y1 = edges[:, 0] - ax, edges[:, 1] - ay  # (S, E), relative to a
    x2, y2 = edges[:, 2] - ax, edges[:, 3] - ay
    t1 = x1 * ux + y1 * uy
    t2 = x2 * ux + y2 * uy
    n1 = y1 * ux - x1 * uy
    n2 = y2 * ux - x2 * uy
    L, R = length[:, None] + margin, r[:, None]
    along = (np.maximum(t1, t2) >= -margin) & (np.minimum(t1, t2) <= L)
    across = (np.maximum(n1, n2) >= -R) & (np.minimum(n1, n2) <= R)
    contour, edge = np.nonzero(along & across)
    dt = t2[contour, edge] - t1[contour, edge]  # the angle only where the window is reached
    dn = n2[contour, edge] - n1[contour, edge]
    keep = np.arctan2(np.abs(dn), np.abs(dt)) <= 3.0 * params.sigma_phi
    return contour[keep], edge[keep]


def contour_scores(
    a: np.ndarray,
    b: np.ndarray,
    edges: np.ndarray,
    contour: np.ndarray,
    edge: np.ndarray,
    params: SimilarityParams,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """s_i of the best edge per window (eq. 7, 8) for contours a, b (N, S, 2) and candidate pairs.

    (N, S).  Each edge is cut to the window 0 <= t <= l_M, |n| <= r of the contour (t along it
    from a, n across it), clipping from the edge's first endpoint (x1, y1): only a pair whose first
    endpoint lies in the window scores.  NOTE: that is the behaviour of the clipping this function
    has always done (its Liang-Barsky loop emptied the cut for any side the first endpoint was
    outside, even where the edge runs into the window), kept unchanged so scores stay bit for bit
    the same; an edge that enters the window from outside scores 0, and the same edge reversed
    scores.  The first-endpoint test runs on all N x P (shift, pair) elements, the rest of eq. 7, 8
    only on the few (about 5 %) that pass it.
    """
    N, S = a.shape[:2]
    best = np.zeros((N, S))
    if S == 0 or len(contour) == 0:
        return best
    # float32: half the memory traffic; contour-major (S, N) so that a pair's contour is one row
    a = a.astype(np.float32).transpose(2, 1, 0)  # (2, S, N)
    b = b.astype(np.float32).transpose(2, 1, 0)
    dx, dy = b[0] - a[0], b[1] - a[1]
    length = np.sqrt(dx * dx + dy * dy)  # l_M (S, N)
    scale = np.maximum(length, 1e-9)
    r = np.maximum(params.c_r * length, params.min_window)  # window half-width
    ux, uy = (dx / scale)[contour], (dy / scale)[contour]  # (P, N)
    ax, ay = a[0][contour], a[1][contour]
    L, R = length[contour], r[contour]
    e = edges[edge].astype(np.float32)
    x1, y1 = e[:, 0:1], e[:, 1:2]  # (P, 1)
    dx1, dy1 = x1 - ax, y1 - ay
    t1 = dx1 * ux
    t1 += dy1 * uy
    n1 = dy1 * ux
    n1 -= dx1 * uy
    inside = t1 >= 0
    inside &= t1 <= L
    inside &= n1 >= -R
    inside &= n1 <= R
    idx = np.flatnonzero(inside)  # p * N + n
    t1, n1, L, R, ux, uy, ax, ay = (v.ravel().take(idx) for v in (t1, n1, L, R, ux, uy, ax, ay))
    pair = idx // N
    x2, y2 = e[:, 2].take(pair), e[:, 3].take(pair)
    t2 = (x2 - ax) * ux + (y2 - ay) * uy
    n2 = (y2 - ay) * ux - (x2 - ax) * uy
    dt, dn = t2 - t1, n2 - n1
    # the cut piece is lambda in [0, lam_hi] along the edge: p * lambda <= q for each side
    # (q >= 0 for all four: the first endpoint is inside)
    lam_hi = np.ones_like(t1)
    with np.errstate(divide='ignore', invalid='ignore'):
        for p, q in ((-dt, t1), (dt, L - t1), (-dn, R + n1), (dn, R - n1)):
            np.minimum(lam_hi, np.where(p > 0, q / p, 1.0), out=lam_hi)
    cut = np.flatnonzero(lam_hi > 0)
    idx, pair, dt, dn, n1, L, R, lam_hi = (
        v.take(cut) for v in (idx, pair, dt, dn, n1, L, R, lam_hi)
    )
    overlap = np.abs(dt) * lam_hi  # l_i: projection onto the model line
    middle = np.abs(n1 + dn * lam_hi / 2.0)  # d_i
    angle = np.arctan2(np.abs(dn), np.abs(dt))  # dphi_i in [0, pi/2]
    exponent = (
        ((L - overlap) / (params.c_l * L)) ** 2
        + (middle / (params.c_d * R)) ** 2
        + (angle / params.sigma_phi) ** 2
    )
    s = overlap * np.exp(-0.5 * exponent)  # eq. 7
    if weights is not None:  # w_G per edge
        s = s * weights[edge[pair]]
    shift = idx - pair * N
    np.maximum.at(best.ravel(), shift * S + contour[pair], s.astype(float))  # best edge per window
    invalid = ~np.isfinite(length)  # a contour not in front of the camera: its windows score NaN
    if invalid.any():
        scored = np.zeros(S, bool)
        scored[contour] = True
        best[invalid.T & scored] = np.nan
    return best


def similarity(
    a: np.ndarray,
    b: np.ndarray,
    edges: np.ndarray,
    contour: np.ndarray,
    edge: np.ndarray,
    params: SimilarityParams,
    part_weights: np.ndarray | None = None,
) -> np.ndarray:
    """s(p) of eq. 11 for N shifted copies of the contours (a, b: (N, S, 2)): (N,)."""
    if a.shape[1] == 0:
        return np.zeros(a.shape[0])
    weights = gradient_weights(edges) if params.gradient_weight else None
    best = contour_scores(a, b, edges, contour, edge, params, weights)
    total = np.linalg.norm(b - a, axis=-1).sum(axis=1)
    w_k = 1.0 if part_weights is None else part_weights[None]
    return (w_k * best).sum(axis=1) / np.maximum(total, 1e-9)


def gradient_weights(edges: np.ndarray) -> np.ndarray:
    """w_G: each edge line's gradient magnitude over the mean of the frame's edges (E,)."""
    magnitude = edges[:, 4] if edges.shape[1] > 4 else np.ones(len(edges))
    mean = magnitude.mean() if len(magnitude) else 1.0
    return magnitude / max(mean, 1e-9)


def edge_table(edges) -> np.ndarray:
    """Return an EDGE_DTYPE record array (or an (E, >=4) array) as a float (E, 5) array x1, y1, x2.

    y2, magnitude.
    """
    if getattr(edges, 'dtype', None) is not None and edges.dtype.names:
        return np.stack(
            [edges['x1'], edges['y1'], edges['x2'], edges['y2'], edges['magnitude']], 1
        ).astype(float)
    arr = np.asarray(edges, float).reshape(len(edges), -1)
    return arr if arr.shape[1] >= 5 else np.hstack([arr[:, :4], np.ones((len(arr), 1))])
