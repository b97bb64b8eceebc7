"""Triangulation of 2D keypoints seen by calibrated cameras, as Pose2Sim does it.

Each keypoint of each frame is triangulated by the direct linear transform
over the cameras that see it, each camera's two equations weighted by the
detector's confidence, in undistorted normalised coordinates.  While the
worst camera's reprojection error exceeds a threshold and more than two
cameras remain, that camera is dropped and the point triangulated again.
Two cameras that agree on the wrong limb pass that test, so a point that
leaves its joint's short-term median by more than a body can move in a few
frames is flagged too (:func:`temporal_outliers`).
"""

from __future__ import annotations

from dataclasses import dataclass
import warnings

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from memo_ros.core.geometry.camera import Camera


@dataclass
class Triangulation:
    """3D points, their mean reprojection error and the cameras used.

    Points are NaN where fewer than two cameras saw the keypoint.
    """

    points: np.ndarray
    error_px: np.ndarray  # (F, J) mean reprojection error over the cameras used, pixels
    used: np.ndarray  # (F, J, C) bool


def normalised(cameras: list[Camera], uv: np.ndarray) -> np.ndarray:
    """Return undistorted normalised image coordinates (C, ..., 2) of pixels (C, ..., 2)."""
    out = np.empty(uv.shape, float)
    for c, cam in enumerate(cameras):
        out[c] = cam.ideal_coordinates(uv[c, ..., 0], uv[c, ..., 1])
    return out


def _dlt(P: np.ndarray, xy: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Weighted DLT.

    Points (N, 3) from projections P (C, 3, 4), coordinates (N, C, 2), weights (N, C).
    """
    rows_x = xy[..., 0, None] * P[None, :, 2, :] - P[None, :, 0, :]  # (N, C, 4)
    rows_y = xy[..., 1, None] * P[None, :, 2, :] - P[None, :, 1, :]
    A = np.concatenate([rows_x, rows_y], axis=1) * np.concatenate([weight, weight], 1)[..., None]
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1, :]
    with np.errstate(divide='ignore', invalid='ignore'):
        return X[:, :3] / X[:, 3:4]


def triangulate(
    cameras: list[Camera],
    uv: np.ndarray,
    confidence: np.ndarray,
    min_confidence: float = 0.3,
    max_error_px: float = 15.0,
) -> Triangulation:
    """Triangulate keypoints uv (C, F, J, 2) pixels with confidences (C, F, J) in [0, 1].

    A camera counts for a point when its confidence reaches ``min_confidence``;
    the worst camera is dropped while the point's largest reprojection error is
    above ``max_error_px`` and more than two cameras remain.
    """
    n_cams, frames, joints = confidence.shape
    P = np.stack(
        [np.hstack([c.R_world_cam.T, -c.R_world_cam.T @ c.t_world_cam[:, None]]) for c in cameras]
    )
    xy = np.moveaxis(normalised(cameras, uv), 0, 2).reshape(-1, n_cams, 2)  # (N, C, 2)
    pix = np.moveaxis(uv, 0, 2).reshape(-1, n_cams, 2)
    conf = np.moveaxis(confidence, 0, 2).reshape(-1, n_cams)
    used = (conf >= min_confidence) & np.all(np.isfinite(pix), -1)
    points = np.full((len(conf), 3), np.nan)
    error = np.full((len(conf), n_cams), np.nan)
    for _ in range(n_cams - 1):  # each pass may drop one camera per point
        ok = used.sum(1) >= 2
        if not ok.any():
            break
        weight = np.where(used[ok], conf[ok], 0.0)
        X = _dlt(P, np.nan_to_num(xy[ok]), weight)
        reproj = np.stack([cam.project(X) for cam in cameras], 1)  # (n, C, 2)
        err = np.linalg.norm(reproj - pix[ok], axis=-1)
        err = np.where(used[ok], err, np.nan)
        points[ok] = X
        error[ok] = err
        worst = np.nanargmax(np.where(used[ok], err, -1.0), axis=1)
        drop = (np.nanmax(np.where(used[ok], err, -1.0), axis=1) > max_error_px) & (
            used[ok].sum(1) > 2
        )
        if not drop.any():
            break
        rows = np.flatnonzero(ok)[drop]
        used[rows, worst[drop]] = False
    points[used.sum(1) < 2] = np.nan
    counted = used & np.isfinite(error)
    mean_error = np.where(counted, error, 0.0).sum(1) / np.maximum(counted.sum(1), 1)
    mean_error[~counted.any(1)] = np.nan
    return Triangulation(
        points.reshape(frames, joints, 3),
        mean_error.reshape(frames, joints),
        used.reshape(frames, joints, n_cams),
    )


def temporal_outliers(
    points: np.ndarray, window: int = 5, max_deviation_m: float = 0.25
) -> np.ndarray:
    """Flag points (F, J, 3) farther than ``max_deviation_m`` from their joint's running median.

    The median is taken over ``window`` frames centred on each frame (edges
    repeated), per joint and coordinate, so one or two wrong frames in a row
    cannot move it: a detector that takes a wrist for an elbow in two views
    gives a point that reprojects well there and still jumps by a metre.
    Returns (F, J) bool; missing points are not flagged.
    """
    half = window // 2
    padded = np.pad(points, ((half, half), (0, 0), (0, 0)), mode='edge')
    windows = sliding_window_view(padded, window, axis=0)  # (F, J, 3, window)
    with warnings.catch_warnings():
        warnings.filterwarnings('ignore', 'All-NaN slice', RuntimeWarning)  # a joint never seen
        median = np.nanmedian(windows, axis=-1)
    deviation = np.linalg.norm(points - median, axis=-1)
    return np.nan_to_num(deviation, nan=0.0) > max_deviation_m
