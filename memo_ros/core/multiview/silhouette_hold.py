"""The silhouette holds the body: no part of the model may project outside what a camera sees.

Kakadiaris & Metaxas pull the model only from the data side: each occluding-contour sample pulls
its nearest model node (eq. 13-14).  A limb whose nodes no sample reaches is pulled by nothing, so
when the samples of one limb are taken by its neighbour (an arm raised in front of the other, a
leg kicked past the other) the wrong limb follows them and the right one is left where no
camera sees anything, with the contour fit as good as before.  Every surface point of the body
lies inside the silhouette of every camera that sees it, so a model outline node that projects
outside a camera's silhouette is wrong by at least its distance to it.  That distance, beyond a
tolerance, is a one-sided measurement (like the joint ranges): zero inside, and outside a pull
along the distance's gradient towards the silhouette.

A real segmentation misses parts of the person (dark shorts against a dark floor), and a hold on
the silhouette itself pulls the model's parts into what is left.  The weaker condition holds
there too: every surface point lies inside the convex hull of every silhouette that sees it, and a
part the segmentation missed between the others is still inside that hull.  So the hold can use
each camera's convex hull of its contours instead (``hull``): it still pulls in a limb left where
nothing is (beside or above the person), and no longer one that the silhouette lacks inside its
outline.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from memo_ros.core.geometry.camera import Camera

SCALE = 0.5  # the distance map is kept at half the image's resolution: a pull needs no finer
MARGIN_PX = 48.0  # the map covers the silhouette's box grown by this much; beyond, it is extended
BORDER_PX = 3.0  # nodes this near the image border (or beyond) are not held: the view is cut there
_SHIFT = 3  # fractional bits of the polygon's vertices (cv2.fillPoly): sub-pixel outlines


@dataclass
class SilhouetteField:
    """Distance outside one camera's silhouette around it, at reduced resolution.

    ``distance`` covers the full-resolution box [x0, x0 + w / scale) x [y0, y0 + h / scale).
    """

    distance: np.ndarray  # (h, w) float32, in full-resolution pixels
    x0: float
    y0: float
    scale: float
    width: int  # the image's
    height: int

    @classmethod
    def from_contours(
        cls, camera: Camera, table: np.ndarray, scale: float = SCALE, hull: bool = False
    ) -> 'SilhouetteField | None':
        """Rasterise a camera's closed occluding contours (holes by the even-odd rule).

        With ``hull``, the convex hull of all its contour samples instead.  None without a contour
        of at least three samples.
        """
        x, y = np.asarray(table['x'], float), np.asarray(table['y'], float)
        if len(x) < 3:
            return None
        ids = np.asarray(table['contour'])
        if hull:
            corners = cv2.convexHull(np.stack([x, y], -1).astype(np.float32))[:, 0].astype(float)
            x, y, ids = corners[:, 0], corners[:, 1], np.zeros(len(corners), np.uint32)
        x0 = max(float(np.floor(x.min() - MARGIN_PX)), 0.0)
        y0 = max(float(np.floor(y.min() - MARGIN_PX)), 0.0)
        x1 = min(float(np.ceil(x.max() + MARGIN_PX)), float(camera.width))
        y1 = min(float(np.ceil(y.max() + MARGIN_PX)), float(camera.height))
        w = max(int(np.ceil((x1 - x0) * scale)), 2)
        h = max(int(np.ceil((y1 - y0) * scale)), 2)
        # pixel centres at integers: a full-resolution pixel edge u maps to (u - x0) * scale - 0.5
        fixed = np.stack([(x - x0) * scale - 0.5, (y - y0) * scale - 0.5], -1) * (1 << _SHIFT)
        cuts = np.flatnonzero(np.diff(ids)) + 1
        polygons = [np.round(p).astype(np.int32) for p in np.split(fixed, cuts) if len(p) >= 3]
        if not polygons:
            return None
        mask = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask, polygons, 1, cv2.LINE_8, _SHIFT)
        if not mask.any():
            return None
        outside = cv2.distanceTransform(1 - mask, cv2.DIST_L2, cv2.DIST_MASK_5)
        return cls(outside / scale, x0, y0, scale, camera.width, camera.height)

    def lookup(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (held, distance, direction) at full-resolution pixels uv (N, 2).

        Bilinear in the map, the direction its gradient (away from the silhouette); beyond the map
        the distance grows by the way out and the direction is the map border's.  ``held`` is
        False where uv is not finite or within BORDER_PX of the image border.
        """
        uv = np.asarray(uv, float)
        finite = np.all(np.isfinite(uv), axis=1)
        safe = np.where(finite[:, None], uv, 0.0)
        held = (
            finite
            & (safe[:, 0] >= BORDER_PX)
            & (safe[:, 1] >= BORDER_PX)
            & (safe[:, 0] <= self.width - 1 - BORDER_PX)
            & (safe[:, 1] <= self.height - 1 - BORDER_PX)
        )
        h, w = self.distance.shape
        gx = (safe[:, 0] - self.x0) * self.scale - 0.5
        gy = (safe[:, 1] - self.y0) * self.scale - 0.5
        cx, cy = np.clip(gx, 0.0, w - 1.001), np.clip(gy, 0.0, h - 1.001)
        beyond = np.hypot(gx - cx, gy - cy) / self.scale
        c0, r0 = cx.astype(int), cy.astype(int)
        fx, fy = cx - c0, cy - r0
        d = self.distance
        d00, d01 = d[r0, c0], d[r0, c0 + 1]
        d10, d11 = d[r0 + 1, c0], d[r0 + 1, c0 + 1]
        top, bottom = d00 + fx * (d01 - d00), d10 + fx * (d11 - d10)
        distance = top + fy * (bottom - top) + beyond
        ddx = (1 - fy) * (d01 - d00) + fy * (d11 - d10)
        ddy = bottom - top
        direction = np.stack([ddx, ddy], -1)
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-9)
        return held, distance.astype(float), direction


def silhouette_fields(
    cameras: dict[str, Camera], contours: dict[str, np.ndarray], hull: bool = False
) -> dict[str, SilhouetteField]:
    """Return each camera's :class:`SilhouetteField` from its contour table.

    Of the contours' convex hull with ``hull``.  Cameras without a contour are left out.
    """
    fields = {}
    for name, table in contours.items():
        field = SilhouetteField.from_contours(cameras[name], table, hull=hull)
        if field is not None:
            fields[name] = field
    return fields


def outside_pull(
    field: SilhouetteField, uv: np.ndarray, tolerance_px: float, cap_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (nodes, direction, residual) of the nodes at ``uv`` held outside the silhouette.

    The residual is the image motion along ``direction`` (pointing away from the silhouette) that
    would bring a node back within ``tolerance_px``, capped at ``cap_px`` so that a far node pulls
    like a near one and the update's gate keeps it (it is relinearised every iteration).
    """
    held, distance, direction = field.lookup(uv)
    out = np.flatnonzero(held & (distance > tolerance_px))
    residual = -np.minimum(distance[out] - tolerance_px, cap_px)
    return out, direction[out], residual
