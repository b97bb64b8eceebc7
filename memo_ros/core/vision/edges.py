"""Rohr §4.3: grey-value edge lines inside the person's enclosing rectangle.

"Inside the detected rectangle we compute edge points [...], link them
together, and approximate them by eigenvector line fitting."  Here:

1. edge points: 3x3 Sobel gradient, non-maximum suppression and hysteresis
   (``cv2.Canny`` on the precomputed gradient, L2 magnitude) in the rectangle
   grown by a small margin;
2. linking: ``cv2.findContours`` traces every 8-connected edge curve; keeping
   only each pixel's first visit turns the traces (which run along an open
   curve and back) into ordered chains, split at junctions;
3. splitting: each chain is cut recursively at its farthest point from the
   chord (Douglas-Peucker, ``cv2.approxPolyDP``) until every point lies within
   ``tolerance`` of its piece;
4. eigenvector line fitting (Duda & Hart): a piece's line runs through the
   centroid along the principal eigenvector of the points' covariance; the
   endpoints are the projections of the extreme points onto that line.

Each line carries the mean gradient magnitude of its points and its chain id.
"""

from __future__ import annotations

import cv2
import numpy as np

EDGE_DTYPE = np.dtype(
    [
        ('x1', '<f4'),
        ('y1', '<f4'),
        ('x2', '<f4'),
        ('y2', '<f4'),
        ('magnitude', '<f4'),
        ('chain', '<u4'),
    ]
)


def _roi(
    box: tuple[int, int, int, int] | None, margin: int, shape: tuple[int, int]
) -> tuple[int, int, int, int]:
    """Return ``box`` grown by ``margin`` and clipped to the image, as (x0, y0, x1, y1)."""
    height, width = shape
    if box is None:
        return 0, 0, width, height
    x, y, w, h = (int(v) for v in box)
    return (
        max(x - margin, 0),
        max(y - margin, 0),
        min(x + w + margin, width),
        min(y + h + margin, height),
    )


def edge_chains(edge_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ordered chains of an 8-connected edge map.

    Points (N, 2) int32 (x, y) and chain ids (N,), chains contiguous.
    """
    traces, _ = cv2.findContours(edge_map, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    if not traces:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.int64)
    points = np.concatenate([t.reshape(-1, 2) for t in traces])
    trace_id = np.repeat(np.arange(len(traces)), [len(t) for t in traces])
    key = points[:, 1].astype(np.int64) * edge_map.shape[1] + points[:, 0]
    first = np.zeros(len(points), bool)
    first[np.unique(key, return_index=True)[1]] = True  # each pixel's first visit over all traces
    # a chain is a run of consecutive first visits within one trace
    start = first & ~np.r_[False, first[:-1] & (trace_id[1:] == trace_id[:-1])]
    chain = np.cumsum(start) - 1
    return points[first], chain[first]


def _closed_chains(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Which chains are traced loops: at least 8 points and the two ends 8-neighbours."""
    gap = np.abs(points[starts] - points[ends - 1]).max(axis=1)
    return (ends - starts >= 8) & (gap <= 1)


def _loop_vertices(
    points: np.ndarray, chain: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]]:
    """Return the closed chains rotated to start at a corner and closed on it.

    With their closed-polygon vertices.
    """
    starts = np.flatnonzero(np.r_[True, chain[1:] != chain[:-1]])
    ends = np.r_[starts[1:], len(points)]
    closed = np.flatnonzero(_closed_chains(points, starts, ends))
    if closed.size == 0:
        return points, chain, {}
    parts, ids, loops, previous = [], [], {}, 0
    for c in closed:  # loops are few
        a, b = starts[c], ends[c]
        loop = points[a:b]
        corners = cv2.approxPolyDP(loop.reshape(-1, 1, 2), tolerance, True).reshape(-1, 2)
        at = int(np.flatnonzero((loop[:, 0] == corners[0, 0]) & (loop[:, 1] == corners[0, 1]))[0])
        rolled = np.roll(loop, -at, axis=0)
        parts += [points[previous:a], rolled, rolled[:1]]
        ids += [chain[previous:a], chain[a:b], chain[a : a + 1]]
        loops[int(chain[a])] = np.vstack([corners, corners[:1]])
        previous = b
    parts.append(points[previous:])
    ids.append(chain[previous:])
    return np.concatenate(parts), np.concatenate(ids), loops


def split_chains(
    points: np.ndarray, chain: np.ndarray, tolerance: float, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Douglas-Peucker split of contiguous chains.

    Points with inner vertices doubled, piece and chain ids.
    """
    # recursive splitting at the farthest point (cv2.approxPolyDP) per chain; the vertices are
    # chain
    # pixels, located through an image of positions; a vertex ends one piece and starts the next.
    # A loop is split as a closed polygon, starting and ending at one of its corners.
    points, chain, loops = _loop_vertices(points, chain, tolerance)
    starts = np.flatnonzero(np.r_[True, chain[1:] != chain[:-1]])
    ends = np.r_[starts[1:], len(points)]
    pieces = [
        loops[int(chain[a])]
        if loops and int(chain[a]) in loops
        else cv2.approxPolyDP(points[a:b].reshape(-1, 1, 2), tolerance, False).reshape(-1, 2)
        for a, b in zip(starts, ends)
    ]
    counts = np.array([len(v) for v in pieces])
    vertices = np.concatenate(pieces)
    first = np.r_[0, np.cumsum(counts)[:-1]]
    inner = np.ones(len(vertices), bool)
    inner[first] = False
    inner[first + counts - 1] = False
    position = np.full(shape, -1, np.int64)
    position[points[:, 1], points[:, 0]] = np.arange(
        len(points)
    )  # a loop's repeated corner: its end
    cut = position[vertices[inner, 1], vertices[inner, 0]]
    reps = np.ones(len(points), np.int64)
    reps[cut] = 2
    index = np.repeat(np.arange(len(points)), reps)
    is_start = np.zeros(len(points), bool)
    is_start[starts] = True
    new_piece = np.r_[True, index[1:] == index[:-1]] | is_start[index]
    piece = np.cumsum(new_piece) - 1
    return points[index], piece, chain[index]


def fit_lines(
    points: np.ndarray, piece: np.ndarray, weights_at: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvector line fit of contiguous pieces.

    Endpoints (K, 2, 2), lengths (K,), mean weight (K,).
    """
    p = points.astype(np.float64)
    starts = np.flatnonzero(np.r_[True, piece[1:] != piece[:-1]])
    n = np.diff(np.r_[starts, len(p)]).astype(np.float64)
    index = np.repeat(np.arange(len(starts)), n.astype(np.int64))
    mean = np.stack([np.bincount(index, p[:, 0]) / n, np.bincount(index, p[:, 1]) / n], axis=1)
    d = p - mean[index]
    cxx = np.bincount(index, d[:, 0] * d[:, 0])
    cyy = np.bincount(index, d[:, 1] * d[:, 1])
    cxy = np.bincount(index, d[:, 0] * d[:, 1])
    angle = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # principal eigenvector of the 2x2 covariance
    direction = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    t = np.einsum('ij,ij->i', d, direction[index])
    t_min = np.minimum.reduceat(t, starts)
    t_max = np.maximum.reduceat(t, starts)
    ends = t[np.r_[starts[1:], len(p)] - 1]
    forward = ends >= t[starts]  # keep the chain's direction of travel
    t1, t2 = np.where(forward, t_min, t_max), np.where(forward, t_max, t_min)
    endpoints = np.stack([mean + t1[:, None] * direction, mean + t2[:, None] * direction], axis=1)
    weight = (
        np.bincount(index, weights_at) / n if weights_at is not None else np.zeros(len(starts))
    )
    return endpoints, t_max - t_min, weight


def edge_lines(
    grey: np.ndarray,
    box: tuple[int, int, int, int] | None = None,
    low: float = 30.0,
    high: float = 80.0,
    min_length: float = 6.0,
    tolerance: float = 1.5,
    margin: int = 3,
) -> np.ndarray:
    """Straight edge lines of ``grey`` inside ``box`` (x, y, w, h; None = whole image).

    An EDGE_DTYPE table.
    """
    grey = np.asarray(grey)
    x0, y0, x1, y1 = _roi(box, margin, grey.shape[:2])
    if x1 - x0 < 3 or y1 - y0 < 3:
        return np.zeros(0, EDGE_DTYPE)
    roi = np.ascontiguousarray(grey[y0:y1, x0:x1])
    dx = cv2.Sobel(roi, cv2.CV_16S, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    dy = cv2.Sobel(roi, cv2.CV_16S, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    edge_map = cv2.Canny(dx, dy, float(low), float(high), L2gradient=True)
    points, chain = edge_chains(edge_map)
    if len(points) == 0:
        return np.zeros(0, EDGE_DTYPE)
    # chains shorter than the shortest line cannot give one
    starts = np.flatnonzero(np.r_[True, chain[1:] != chain[:-1]])
    sizes = np.diff(np.r_[starts, len(points)])
    long_enough = np.repeat(sizes >= max(min_length, 2.0), sizes)
    points, chain = points[long_enough], chain[long_enough]
    if len(points) == 0:
        return np.zeros(0, EDGE_DTYPE)
    points, piece, chain = split_chains(points, chain, tolerance, edge_map.shape)
    piece_chain = chain[np.flatnonzero(np.r_[True, piece[1:] != piece[:-1]])]
    gx = dx[points[:, 1], points[:, 0]].astype(np.float64)
    gy = dy[points[:, 1], points[:, 0]].astype(np.float64)
    endpoints, length, magnitude = fit_lines(points, piece, np.hypot(gx, gy))
    keep = length >= min_length
    table = np.empty(int(keep.sum()), EDGE_DTYPE)
    table['x1'], table['y1'] = endpoints[keep, 0, 0] + x0, endpoints[keep, 0, 1] + y0
    table['x2'], table['y2'] = endpoints[keep, 1, 0] + x0, endpoints[keep, 1, 1] + y0
    table['magnitude'] = magnitude[keep]
    table['chain'] = piece_chain[keep]
    return table


def merge_boxes(boxes: list[tuple[int, int, int, int]]) -> list[tuple[int, int, int, int]]:
    """Rectangles (x, y, w, h) with every overlapping pair replaced by their union.

    Until none overlap.
    """
    merged = [(int(x), int(y), int(w), int(h)) for x, y, w, h in boxes]
    changed = True
    while changed and len(merged) > 1:
        changed = False
        for i in range(len(merged)):
            for j in range(i + 1, len(merged)):
                (ax, ay, aw, ah), (bx, by, bw, bh) = merged[i], merged[j]
                if ax < bx + bw and bx < ax + aw and ay < by + bh and by < ay + ah:
                    x0, y0 = min(ax, bx), min(ay, by)
                    x1, y1 = max(ax + aw, bx + bw), max(ay + ah, by + bh)
                    merged[i] = (x0, y0, x1 - x0, y1 - y0)
                    del merged[j]
                    changed = True
                    break
            if changed:
                break
    return merged


def edge_lines_in_boxes(
    grey: np.ndarray,
    boxes: list[tuple[int, int, int, int]],
    low: float = 30.0,
    high: float = 80.0,
    min_length: float = 6.0,
    tolerance: float = 1.5,
    margin: int = 3,
) -> np.ndarray:
    """Edge lines inside each of several rectangles (overlapping ones merged, margins included).

    Chain ids unique.
    """
    tables, next_chain = [], 0
    grown = [(x - margin, y - margin, w + 2 * margin, h + 2 * margin) for x, y, w, h in boxes]
    for x, y, w, h in merge_boxes(grown):
        table = edge_lines(grey, (x, y, w, h), low, high, min_length, tolerance, margin=0)
        if len(table):
            table['chain'] += next_chain
            next_chain = int(table['chain'].max()) + 1
            tables.append(table)
    return np.concatenate(tables) if tables else np.zeros(0, EDGE_DTYPE)
