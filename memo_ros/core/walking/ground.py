"""A walker's depth and height from the ground plane, without an assumed height.

Rohr §4.2 (eq. 2-6) needs the person's height H to place the sole.  Where the ground is known
(DESIGN.md: world z = 0 is the ground), eq. 3 with the sole on it, ``X_u = (X, Y, g)``, has only
three unknowns (X, Y, h_u): the ray through the rectangle's bottom midpoint meets the ground at the
sole.  Eq. 4 then has two, h_o and H: the ray through the top midpoint meets the vertical through
the sole at the top of the head, so H is measured, not assumed.  The midpoints are first shifted
onto the image line through the rectangle's centre and the vertical's vanishing point, as the
paper prescribes for eq. 6, so eq. 5 holds exactly.

The rectangle's bottom is not under the pelvis: it is the outline's lowest image point, the rim of
whichever foot reaches lowest (at 11 m and 1.5 m camera height one pixel there is 8 cm of depth,
and a foot lifted 1 cm looks 7 cm nearer), and its top is the near rim of the head.
:func:`rectangle_offsets` projects the walking model posed at the estimated state, takes the
rectangle of its outline and solves the same equations on it: the model's pelvis minus the model's
sole is the offset from the measured sole to the pelvis, and the measured over the model's
rectangle height scales the model's standing height to the person's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from memo_ros.core.geometry.body import Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.walking.position import (
    UP,
    ideal_pixels,
    projection_matrix,
    shift_to_vertical,
)


@dataclass
class GroundPosition:
    """Eq. 3-5 with the sole on the ground: sole and head-top points, the height they span."""

    sole: np.ndarray  # X_u (3,), world metres, on the ground
    top: np.ndarray  # X_u + H (3,)
    height: float  # H (m), measured
    bottom_px: np.ndarray  # x_u after the shift (2,), ideal pixels
    top_px: np.ndarray  # x_o after the shift (2,), ideal pixels


def position_on_ground(
    camera: Camera, bottom_px: np.ndarray, top_px: np.ndarray, ground_z: float = 0.0
) -> GroundPosition:
    """Sole on the ground z = ``ground_z`` and height H from the rectangle's midpoints (pixels).

    ValueError when the bottom ray does not reach the ground in front of the camera.
    """
    T = projection_matrix(camera)
    bottom, top = ideal_pixels(camera, np.array([bottom_px, top_px], float))
    if np.allclose(bottom, top):
        raise ValueError('the rectangle has no height: bottom and top midpoints coincide')
    bottom, top = shift_to_vertical(T, bottom, top)  # the perpendicularity condition, eq. 5
    x_u, x_o = np.append(bottom, 1.0), np.append(top, 1.0)
    vanishing = T[:, :3] @ UP
    # eq. 3 with Z_u = g: T[:, :2] (X, Y) - h_u x_u = -(T[:, 2] g + T[:, 3])
    A = np.column_stack([T[:, 0], T[:, 1], -x_u])
    if np.linalg.cond(A) > 1e12:
        raise ValueError("the rectangle's bottom ray runs parallel to the ground")
    X, Y, h_u = np.linalg.solve(A, -(T[:, 2] * ground_z + T[:, 3]))
    if h_u <= 0:
        raise ValueError("the rectangle's bottom ray meets the ground behind the camera")
    # eq. 4 with H unknown: h_o x_o - H T UP = h_u x_u (consistent after the shift)
    (h_o, height), *_ = np.linalg.lstsq(np.column_stack([x_o, -vanishing]), h_u * x_u, rcond=None)
    if h_o <= 0 or height <= 0:
        raise ValueError("the rectangle's top is not above its bottom on the ground")
    sole = np.array([X, Y, ground_z])
    return GroundPosition(sole, sole + height * UP, float(height), x_u[:2], x_o[:2])


def outline_midpoints(
    camera: Camera, body: Body, rotations: np.ndarray, origins: np.ndarray, samples: int = 72
) -> tuple[np.ndarray, np.ndarray]:
    """Bottom and top midpoints (pixels) of the rectangle enclosing the posed model's outline.

    Each part is the convex hull of its two end ellipses, so the outline's extremes lie on them:
    their projected samples give the rectangle exactly, with no pixel grid.
    """
    theta = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    a, b = body.semi_axes[:, :1], body.semi_axes[:, 1:]
    ring = np.stack([a * np.cos(theta), b * np.sin(theta), np.zeros((len(a), samples))], -1)
    far = ring.copy()
    far[..., 2] = body.lengths[:, None]
    rims = np.concatenate([ring, far], 1)  # (P, 2 samples, 3) in each part's frame
    uv = camera.project(np.einsum('pij,pkj->pki', rotations, rims) + origins[:, None, :])
    uv = uv.reshape(-1, 2)
    if not np.isfinite(uv).all():
        raise ValueError('the model is not in front of the camera at this state')
    (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
    return np.array([(u0 + u1) / 2.0, v1]), np.array([(u0 + u1) / 2.0, v0])


@dataclass
class RectangleOffsets:
    """What the model's own rectangle says about a measured one at the same state."""

    pelvis_from_sole: np.ndarray  # (3,) model pelvis minus the model rectangle's sole, world
    rectangle_height: float  # H of the model's rectangle (m)
    standing_height: float  # the model's standing height (m), top of the head in the rest pose


def rectangle_offsets(
    camera: Camera, body: Body, rotations: np.ndarray, origins: np.ndarray, ground_z: float = 0.0
) -> RectangleOffsets:
    """Solve the posed model's own rectangle on the ground: where its sole and height come out."""
    found = position_on_ground(
        camera, *outline_midpoints(camera, body, rotations, origins), ground_z
    )
    return RectangleOffsets(origins[0] - found.sole, found.height, body.standing_height())
