"""Rohr §4.2: 3D position of a walker from the enclosing rectangle and an assumed height (eq. 2-6).

The midpoints of the rectangle's bottom and top edges, ``x_u`` and ``x_o``, are
the images of the sole ``X_u`` and of the top of the head ``X_u + H`` (H along
world +z: the person stands upright on the ground).  With the 3x4 projection
``T`` (rows 1, 2 and 4 of the paper's 4x4 matrix) of ideal (undistorted) pixels,
eq. 6 ``T* X* + b* = 0`` has six equations for ``X* = (X_u, Y_u, Z_u, h_u, h_o)``.
As the paper prescribes, the midpoints are shifted so that its last three
equations (the perpendicularity condition, eq. 5) hold exactly: both move onto
the image line through the rectangle's centre and the vanishing point of the
vertical.  Then h_u, h_o follow from eq. 5 and X_u from the first three rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from memo_ros.core.geometry.camera import Camera

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class BoxPosition:
    """Eq. 2-6's solution.

    Sole and head-top points in world, the shifted midpoints and the scale factors.
    """

    sole: np.ndarray  # X_u (3,), world metres
    top: np.ndarray  # X_u + H (3,)
    bottom_px: np.ndarray  # x_u after the shift (2,), ideal pixels
    top_px: np.ndarray  # x_o after the shift (2,), ideal pixels
    h_u: float
    h_o: float


def projection_matrix(camera: Camera) -> np.ndarray:
    """Return the 3x4 matrix T of eq. 2 (rows 1, 2, 4 of Rohr's 4x4) for ideal pixels.

    K [R^T | -R^T t].
    """
    R = camera.R_world_cam
    return camera.K @ np.hstack([R.T, (-R.T @ camera.t_world_cam)[:, None]])


def ideal_pixels(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Measured pixels (..., 2) with the lens distortion removed (ideal pinhole pixels)."""
    uv = np.asarray(uv, float)
    if not camera.has_distortion:
        return uv.copy()
    K = camera.K
    yd = (uv[..., 1] - K[1, 2]) / K[1, 1]
    xd = (uv[..., 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    xy = camera.undistort(np.stack([xd, yd], -1))
    return np.stack(
        [K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2], K[1, 1] * xy[..., 1] + K[1, 2]], -1
    )


def rohr_system(
    T: np.ndarray, bottom: np.ndarray, top: np.ndarray, height: float
) -> tuple[np.ndarray, np.ndarray]:
    """T* (6, 5) and b* (6,) of eq. 6 for midpoints ``bottom`` = x_u.

    ``top`` = x_o (pixels) and height H.
    """
    (xu, yu), (xo, yo) = bottom, top
    t_star = np.array(
        [
            [*T[0, :3], -xu, 0.0],
            [*T[1, :3], -yu, 0.0],
            [*T[2, :3], -1.0, 0.0],
            [0.0, 0.0, 0.0, xu, -xo],
            [0.0, 0.0, 0.0, yu, -yo],
            [0.0, 0.0, 0.0, 1.0, -1.0],
        ]
    )
    m = height * (T[:, :3] @ UP)  # T H: the height's column (Rohr's Y is our z)
    b_star = np.concatenate([T[:, 3], m])
    return t_star, b_star


def _project_onto_line(line: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Orthogonal projection of the pixel ``point`` onto the homogeneous line ``line``."""
    a, b, c = line
    distance = (a * point[0] + b * point[1] + c) / (a * a + b * b)
    return point - distance * np.array([a, b])


def shift_to_vertical(
    T: np.ndarray, bottom: np.ndarray, top: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move both midpoints onto the image of the vertical through their centre: eq. 5 then holds.

    Rohr's shift: the line through the centre and the vertical's vanishing point T UP.
    """
    vanishing = T[:, :3] @ UP
    centre = np.append((bottom + top) / 2.0, 1.0)
    line = np.cross(centre, vanishing)
    if np.hypot(line[0], line[1]) < 1e-12:
        raise ValueError('the vertical through the rectangle is degenerate in this camera')
    return _project_onto_line(line, bottom), _project_onto_line(line, top)


def position_from_box(camera: Camera, bottom_px, top_px, height: float) -> BoxPosition:
    """Solve eq. 2-6 for the sole X_u from the rectangle's bottom and top midpoints.

    Measured pixels.
    """
    if not height > 0:
        raise ValueError(f'the assumed person height must be positive, got {height}')
    T = projection_matrix(camera)
    bottom, top = ideal_pixels(camera, np.array([bottom_px, top_px], float))
    if np.allclose(bottom, top):
        raise ValueError('the rectangle has no height: bottom and top midpoints coincide')
    bottom, top = shift_to_vertical(T, bottom, top)
    vanishing = T[:, :3] @ UP
    # eq. 5 (the last three rows of eq. 6): h_u x_u - h_o x_o + T H = 0, now consistent
    m = height * vanishing
    A = np.column_stack([np.append(bottom, 1.0), -np.append(top, 1.0)])
    (h_u, h_o), *_ = np.linalg.lstsq(A, -m, rcond=None)
    if h_u <= 0 or h_o <= 0:
        raise ValueError('the rectangle puts the person behind the camera')
    # the first three rows of eq. 6: T[:, :3] X_u + T[:, 3] = h_u x_u
    sole = np.linalg.solve(T[:, :3], h_u * np.append(bottom, 1.0) - T[:, 3])
    return BoxPosition(sole, sole + height * UP, bottom, top, float(h_u), float(h_o))


def box_midpoints(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bottom and top edge midpoints (pixels) of contour_node's rectangle corners.

    x..x+w, y..y+h bounds.
    """
    corners = np.asarray(corners, float).reshape(-1, 2)
    x0, y0 = (
        corners.min(axis=0) - 0.5
    )  # pixel-index bounds -> edges of the pixels (centres at integers)
    x1, y1 = corners.max(axis=0) - 0.5
    u = (x0 + x1) / 2.0
    return np.array([u, y1]), np.array([u, y0])
