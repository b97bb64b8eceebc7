"""Where the tracked body is in a camera's image: its projection grown by a margin.

The contour node keeps the segmented regions that overlap this region (not
simply the largest: people in the background move too) and learns the
background everywhere outside it.  The body comes as the tracker publishes it
on ``/memo/markers``: one cylinder per part, centred on the part's mid-point,
with its diameters and length as the marker's scale.
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import render_labels


def parts_from_cylinders(
    centres: np.ndarray, rotations: np.ndarray, scales: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Part origins (P, 3), semi-axes (P, 2) and lengths (P,) of cylinders given by centre.

    Rotation, scale.

    ``scales`` are (2 a, 2 b, length) per part, the part's axis is the rotation's z column and its
    origin is half a length below the centre, as
    :func:`memo_ros.ros.body_messages.marker_array_message` writes.
    """
    centres = np.asarray(centres, float).reshape(-1, 3)
    rotations = np.asarray(rotations, float).reshape(-1, 3, 3)
    scales = np.asarray(scales, float).reshape(-1, 3)
    lengths = scales[:, 2]
    origins = centres - rotations[:, :, 2] * (lengths[:, None] / 2.0)
    return origins, scales[:, :2] / 2.0, lengths


def body_region(
    camera: Camera,
    rotations: np.ndarray,
    origins: np.ndarray,
    semi_axes: np.ndarray,
    lengths: np.ndarray,
    shape: tuple[int, int],
    margin_px: float,
    scale: float = 0.5,
) -> np.ndarray:
    """Pixels (bool ``shape``) within ``margin_px`` of the body's projection into ``camera``.

    ``shape`` is the image's (height, width); the camera is rescaled to it if its calibration is
    for another size.  The body is rendered at ``scale`` of that size (the margin hides the coarser
    outline).
    """
    height, width = shape
    if (camera.width, camera.height) != (width, height):
        camera = camera.scaled(width / camera.width)
    coarse = render_labels(camera, rotations, origins, semi_axes, lengths, scale=scale).label > 0
    if not coarse.any():
        return np.zeros(shape, bool)
    full = cv2.resize(coarse.view(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST)
    radius = max(int(round(margin_px)), 0)
    if radius:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        full = cv2.dilate(full, kernel)
    return full.view(bool)


def tracked_person(
    camera: Camera,
    bodies: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    stamps: list[int],
    shape: tuple[int, int],
    margin_px: float,
) -> Callable[[int], np.ndarray]:
    """``person_at(i)`` for :func:`~memo_ros.core.vision.background.background_from_frames`.

    The body tracked at ``stamps[i]`` (rotations, origins, semi_axes, lengths) projected and grown
    by ``margin_px``; nowhere when that frame has no tracked body.
    """

    def person_at(i: int) -> np.ndarray:
        body = bodies.get(int(stamps[i]))
        return (
            np.zeros(shape, bool) if body is None else body_region(camera, *body, shape, margin_px)
        )

    return person_at
