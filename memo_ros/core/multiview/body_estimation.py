"""The subject's body dimensions from the first frames' silhouettes of all cameras.

The silhouettes of one frame carve a visual hull out of a voxel grid around
the point where the rays through their centroids meet: a voxel is kept when
every camera that sees it (at least two) sees it inside the person, and the
largest connected piece is the person.  The top of its column over the chest
(a hand raised overhead stands beside it) over the ground is his height in
that posture; over the first frames, the median of the taller half (the
frames where he stands upright; one frame's segmentation error does not
decide) scales the shipped average adult's proportions
(config/body_average_adult.yaml, Winter's segment lengths as fractions of the
standing height).  Few cameras carve a hull taller than the person: the cones of
the head's outlines meet above the head (4 cm on a 1.75 m person in the
orthogonal studio, and a body 2 % too tall turned a third of the simulated
dances round at the start).  So the template, scaled to the measured height and
standing where the hull stands, is imaged into the same cameras and carved the
same way, and the height is lowered by how far its hull overshoots it.  The
girth is scaled with the height: four silhouettes do
not measure a cross-section well enough to tell a slim subject from an
average one (the hull of an ellipse seen from four directions overestimates
it, arms beside the trunk are inside it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from memo_ros.core.geometry.body import Body, PartShape
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import render_labels

HEAD_COLUMN = 0.045  # radius of the column the head's top is sought in, of the hull's extent
# standing heights a measured body may have, m: an adult's (the template's proportions are an
# adult's; below 1.4 m is under the first percentile of adult women), with the measurement's few
# per cent of margin.  Outside them the silhouettes are not one whole person: in a recording
# without empty frames, a person who never moves is learnt into the background, and scraps of
# the room carved hulls 0.5 - 1.1 m tall (the Pose2Sim static trial)
PERSON_HEIGHT_M = (1.3, 2.3)


@dataclass
class HullMeasure:
    """One frame's visual hull: occupied voxel centres (N, 3) of the person and his extent."""

    points: np.ndarray
    bottom: float  # lowest occupied voxel's lower face, m (world z)
    top: float  # the head's top: the highest voxel's upper face in the column over the chest, m

    def height_over(self, ground: float) -> float:
        """Return the head's top over the floor at z = ``ground``, m.

        The hull of the feet reaches below the floor along the cameras' rays: it is not counted.
        """
        return self.top - max(self.bottom, ground)


Silhouettes = tuple[
    list[Camera], list[np.ndarray]
]  # one frame: the cameras and their person masks


def silhouette_from_contours(
    table: np.ndarray, width: int, height: int, scale: float = 1.0
) -> np.ndarray:
    """Return the person mask (bool (height, width)) enclosed by a contour table's closed outlines.

    One per id; ``scale``: the mask is of the image resized by it (as Camera.scaled maps pixels).
    """
    mask = np.zeros((height, width), np.uint8)
    if not len(table):
        return mask.view(bool)
    ids = (
        table['contour']
        if 'contour' in (table.dtype.names or ())
        else np.zeros(len(table), np.uint32)
    )
    xy = np.stack([table['x'], table['y']], axis=1).astype(float)
    if scale != 1.0:
        xy = (xy + 0.5) * scale - 0.5
    polygons = [np.round(xy[ids == i]).astype(np.int32) for i in np.unique(ids)]
    cv2.fillPoly(mask, [p for p in polygons if len(p) >= 3], 1)
    return mask.view(bool)


def frame_silhouettes(cameras: list[Camera], tables: dict[str, np.ndarray]) -> Silhouettes:
    """Return one frame's cameras that have contours and their silhouettes, as estimate_body takes.

    ``tables`` maps camera names to contour tables (the contour nodes' output).
    """
    seen = [c for c in cameras if len(tables.get(c.name, ()))]
    return seen, [silhouette_from_contours(tables[c.name], c.width, c.height) for c in seen]


def ray_meeting_point(cameras: list[Camera], masks: list[np.ndarray]) -> np.ndarray | None:
    """Least-squares meeting point of the rays through each silhouette's centroid.

    None with < 2 cameras.
    """
    A, b = np.zeros((3, 3)), np.zeros(3)
    used = 0
    for camera, mask in zip(cameras, masks):
        ys, xs = np.nonzero(mask)
        if not len(xs):
            continue
        d = camera.pixel_rays(np.array([xs.mean()]), np.array([ys.mean()]))[0]
        projector = np.eye(3) - np.outer(d, d)
        A += projector
        b += projector @ np.asarray(camera.t_world_cam, float)
        used += 1
    return np.linalg.solve(A, b) if used >= 2 else None


def visual_hull(
    cameras: list[Camera],
    masks: list[np.ndarray],
    centre: np.ndarray,
    half_width: float = 1.2,
    z_range: tuple[float, float] = (-0.3, 2.5),
    voxel: float = 0.02,
    tolerance_px: int = 1,
    coarse: float = 0.06,
    fine: float = 0.005,
) -> HullMeasure | None:
    """Return the person's visual hull around ``centre`` (x, y).

    Or None when nothing survives the carving.

    Carved first with ``coarse`` voxels over the whole search box, then with ``voxel``-sized ones
    in the box of the coarse hull's largest piece (grown by two coarse voxels), and its top once
    more with ``fine`` ones.
    """
    low = np.array([centre[0] - half_width, centre[1] - half_width, z_range[0]])
    high = np.array([centre[0] + half_width, centre[1] + half_width, z_range[1]])
    if coarse > voxel:
        rough = _carve(cameras, masks, low, high, coarse, tolerance_px + 1)
        if rough is None:
            return None
        low = np.maximum(low, rough.min(axis=0) - 2 * coarse)
        high = np.minimum(high, rough.max(axis=0) + 2 * coarse)
    points = _carve(cameras, masks, low, high, voxel, tolerance_px)
    if points is None:
        return None
    bottom = float(points[:, 2].min() - voxel / 2)
    head = _head_column(points, bottom, voxel)
    top = float(points[head, 2].max() + voxel / 2)
    if fine < voxel:  # the top again in fine voxels: a height is worth more than a 2 cm step
        crown = points[head & (points[:, 2] > top - 2 * voxel)]
        cap = _carve(
            cameras,
            masks,
            np.append(crown[:, :2].min(axis=0) - voxel, top - 2 * voxel),
            np.append(crown[:, :2].max(axis=0) + voxel, top + voxel),
            fine,
            tolerance_px,
        )
        if cap is not None:
            top = float(cap[:, 2].max() + fine / 2)
    return HullMeasure(points, bottom, top)


def _view_at(camera: Camera, shape: tuple[int, ...]) -> Camera:
    """Return ``camera`` at the resolution of a mask of ``shape`` (rows, columns)."""
    h, w = shape[:2]
    return camera if (camera.width, camera.height) == (w, h) else camera.scaled(w / camera.width)


def _head_column(points: np.ndarray, bottom: float, voxel: float) -> np.ndarray:
    """Return which hull voxels (N,) stand in the column over the chest, where the head is.

    The column's axis is the middle of where the voxels between 55 and 75 % of the hull's extent
    (the chest of a person standing) stand the band's whole height (a leg kicked to hip height
    lies across it), its radius ``HEAD_COLUMN`` of that extent: a hand raised overhead stands
    beside it (a dance's frame measured 2.12 m for 1.75), and so does the ghost that two arms
    raised straight up carve between their cones above the head.
    """
    extent = points[:, 2].max() - bottom
    z = (points[:, 2] - bottom) / max(extent, 1e-9)
    band = (z > 0.55) & (z < 0.75)
    if not band.any():
        return np.ones(len(points), bool)
    # the torso stands through that band: the median of the (x, y) cells it fills nearly all the
    # way up (a limb lying across it fills a few voxels of each)
    xy = points[band, :2]
    cells = np.round((xy - xy.min(axis=0)) / voxel).astype(int)
    counts = np.zeros(cells.max(axis=0) + 1, int)
    np.add.at(counts, tuple(cells.T), 1)
    tall = np.argwhere(counts >= 0.8 * counts.max())
    axis = xy.min(axis=0) + voxel * np.median(tall, axis=0)
    column = np.hypot(*(points[:, :2] - axis).T) < HEAD_COLUMN * extent
    return column if column.any() else np.ones(len(points), bool)


def _carve(
    cameras: list[Camera],
    masks: list[np.ndarray],
    low: np.ndarray,
    high: np.ndarray,
    voxel: float,
    tolerance_px: int,
) -> np.ndarray | None:
    """Centres (N, 3) of the largest connected piece of voxels in every silhouette that sees them.

    A voxel counts when at least 2 cameras see it.
    """
    axes = [np.arange(lo, hi, voxel) + voxel / 2 for lo, hi in zip(low, high)]
    grid = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3)
    inside = np.zeros(len(grid), np.int16)
    seen = np.zeros(len(grid), np.int16)
    kernel = np.ones((2 * tolerance_px + 1, 2 * tolerance_px + 1), np.uint8)
    for camera, mask in zip(cameras, masks):
        h, w = mask.shape
        uv = np.round(_view_at(camera, mask.shape).project(grid))
        ok = np.all(np.isfinite(uv), axis=1)
        u = np.where(ok, uv[:, 0], -1).astype(int)
        v = np.where(ok, uv[:, 1], -1).astype(int)
        ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
        grown = cv2.dilate(mask.view(np.uint8), kernel).view(bool) if tolerance_px else mask
        seen += ok
        inside[ok] += grown[v[ok], u[ok]]
    volume = ((seen >= 2) & (inside == seen)).reshape([len(a) for a in axes])
    labels, count = ndimage.label(volume)
    if count == 0:
        return None
    largest = 1 + int(np.argmax(ndimage.sum_labels(volume, labels, np.arange(1, count + 1))))
    return grid[(labels == largest).reshape(-1)]


def measure_height(
    frames: list[Silhouettes],
    voxel: float = 0.02,
    ground: float = 0.0,
    template: Body | None = None,
) -> tuple[float, list[HullMeasure]]:
    """Return the subject's standing height from several frames' silhouettes.

    And the frames' hulls.

    A frame's height is the hull's top over the ground (z = ``ground``, the world's floor; the hull
    of the feet reaches below it along the cameras' rays); the subject's is the median of the
    frames' heights above their median, i.e. of the frames where he stands tallest (crouching does
    not pull it down).  With a ``template``, less the hull's overshoot over a standing body of
    the template's proportions in those frames (:func:`hull_overshoot`).
    """
    measured = []
    for cameras, masks in frames:
        centre = ray_meeting_point(cameras, masks)
        if centre is None:
            continue
        hull = visual_hull(cameras, masks, centre, voxel=voxel)
        if hull is not None and len(hull.points) > 10:
            measured.append(((cameras, masks), hull))
    if not measured:
        raise ValueError(
            'no frame gives a visual hull: the body needs silhouettes from at least two cameras'
        )
    hulls = [hull for _, hull in measured]
    heights = np.array([h.height_over(ground) for h in hulls])
    upright = np.argsort(heights, kind='stable')[len(heights) // 2 :]
    height = float(np.median(heights[upright]))
    if template is None:
        return height, hulls
    body = scaled_body(template, height)
    overshoots = [
        hull_overshoot(body, measured[k][0], measured[k][1], voxel, ground) for k in upright
    ]
    return height - float(np.median(overshoots)), hulls


def hull_overshoot(
    body: Body, frame: Silhouettes, hull: HullMeasure, voxel: float = 0.02, ground: float = 0.0
) -> float:
    """Return how far the visual hull of ``body`` rises above its standing height, m.

    The body stands (rest pose) on the ground where ``hull`` stands, imaged into ``frame``'s
    cameras at its masks' resolution and carved as the person was.
    """
    cameras, masks = frame
    q = body.neutral()
    q[0:2] = np.median(hull.points[:, :2], axis=0)
    q[2] += ground
    rotations, origins = body.forward_kinematics(q)
    images = []
    for camera, mask in zip(cameras, masks):
        view = _view_at(camera, mask.shape)
        labels = render_labels(view, rotations, origins, body.semi_axes, body.lengths).label
        images.append(labels > 0)
    centre = ray_meeting_point(cameras, images)
    own = visual_hull(cameras, images, centre, voxel=voxel) if centre is not None else None
    if own is None:
        return 0.0
    return own.height_over(ground) - body.standing_height()


def height_problem(
    height: float, low: float = PERSON_HEIGHT_M[0], high: float = PERSON_HEIGHT_M[1]
) -> str | None:
    """Return why ``height`` (m) cannot be the person's standing height, or None when it can."""
    if not np.isfinite(height) or not low <= height <= high:
        return f'{height:.2f} m tall, outside {low:.2f} - {high:.2f} m'
    return None


def scaled_body(template: Body, height: float, name: str | None = None) -> Body:
    """Return the template body scaled to ``height`` (standing height, m).

    Every length, semi-axis and joint offset.
    """
    if not np.isfinite(height) or height <= 0:
        raise ValueError(f'a body height must be positive, got {height}')
    factor = height / template.standing_height()
    shapes = {
        part: PartShape(s.length * factor, s.a * factor, s.b * factor)
        for part, s in template.shapes.items()
    }
    offsets = {
        joint: np.asarray(offset) * factor for joint, offset in template.joint_offsets.items()
    }
    return Body(shapes, offsets, name or f'estimated_{round(height * 100):d}cm')


def estimate_body(
    frames: list[Silhouettes], template: Body, voxel: float = 0.02, ground: float = 0.0
) -> tuple[Body, float]:
    """Return the template scaled to the height measured from the frames' silhouettes.

    The hull's overshoot over a body of the template's proportions taken off (measure_height).

    And that height, m.
    """
    height, _ = measure_height(frames, voxel, ground, template)
    return scaled_body(template, height), height
