"""Rohr §4.3.

Single-image estimation of (X, Y, pose) by grid search on the similarity s(p) (eq. 11).

The walker's parameters: X along the path (world x, pelvis centre), Y the vertical offset of the
walking model (pelvis height = Y + the model's vertical displacement at ``pose``; 0 on flat
ground), Z the depth (world y), and pose. The grid is the paper's (2 cm in X and Y, 0.02 in pose,
every point scored); to make it cheap, the visible contours of a pose value are computed once (one
rendering) at a reference position and moved rigidly in 3D to every (X, Y) grid point, then
projected exactly.  A pose's contours are reused, also in later frames, while the reference lies
within ``reuse_distance`` (25 cm) of the searched position: at 11 m that neglects a change of
viewing direction of about 1 degree (parallax between near and far parts well under a pixel).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import time

import numpy as np

from memo_ros.core.geometry.body import Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.walking.gait import WalkingModel
from memo_ros.core.walking.model_contours import ModelContours, visible_contours
from memo_ros.core.walking.similarity import (
    SimilarityParams,
    candidate_edges,
    similarity,
)


@dataclass
class SearchResult:
    """The best grid point, its similarity.

    The grid's similarity over pose (Rohr Fig. 19) and the cost.
    """

    X: float
    Y: float
    pose: float
    similarity: float
    poses: np.ndarray  # (P,) pose values searched
    curve: np.ndarray  # (P,) best similarity over the (X, Y) grid at each pose
    evaluations: int  # grid points scored (model evaluations of s(p))
    renderings: int  # visibility renderings made (at most one per pose value)
    seconds: float = 0.0


@dataclass
class WalkerModel:
    """The body walking with the gait model in front of one camera, and its visible contours."""

    body: Body
    camera: Camera
    params: SimilarityParams = field(default_factory=SimilarityParams)
    walking: WalkingModel | None = None
    reuse_distance: float = 0.25  # metres; 0 renders every pose value of every search afresh
    renderings: int = 0  # visibility renderings made so far

    def __post_init__(self) -> None:
        self.walking = self.walking or WalkingModel(self.body)
        self._cache: dict[tuple[float, float], tuple[np.ndarray, ModelContours]] = {}

    def clear_cache(self) -> None:
        """Forget the reusable contours (a new walker, a reset)."""
        self._cache.clear()

    def reusable_contours(
        self, position: np.ndarray, pose: float, heading: float
    ) -> tuple[np.ndarray, ModelContours]:
        """Contours of ``pose`` at a reference position within ``reuse_distance`` of ``position``.

        X, Y, Z.
        """
        key = (round(float(np.mod(pose, 1.0)), 9) % 1.0, round(heading, 9))
        hit = self._cache.get(key)
        if hit is not None and np.linalg.norm(hit[0] - position) <= self.reuse_distance:
            return hit
        X, Y, Z = position
        contours = self.contours(X, Y, Z, float(np.mod(pose, 1.0)), heading)
        self.renderings += 1
        if self.reuse_distance > 0:
            self._cache[key] = (position.copy(), contours)
        return position, contours

    def coordinates(self, X: float, Y: float, Z: float, pose, heading: float = 0.0) -> np.ndarray:
        """Generalized coordinates of the walker at (X, Y, Z, pose), facing ``heading``.

        Rad about world z.
        """
        if self.walking is None:
            raise RuntimeError('WalkerModel.walking is None: __post_init__ sets it')
        q = self.walking.coordinates(pose, X, Z, heading)
        q[..., 2] += Y
        return q

    def contours(
        self, X: float, Y: float, Z: float, pose: float, heading: float = 0.0
    ) -> ModelContours:
        """Visible model contours at one state (one rendering)."""
        rotations, origins = self.body.forward_kinematics(self.coordinates(X, Y, Z, pose, heading))
        contours, _ = visible_contours(
            self.camera, rotations, origins, self.body.semi_axes, self.body.lengths
        )
        return contours

    def head_top_height(self) -> float:
        """Mean height of the top of the head over the gait cycle on flat ground.

        The default assumed H.
        """
        q = self.coordinates(0.0, 0.0, 0.0, np.linspace(0.0, 1.0, 50, endpoint=False))
        rotations, origins = self.body.forward_kinematics(q)
        return float(self.body.distal_ends(rotations, origins)[:, 1, 2].mean())

    def search(
        self,
        edges: np.ndarray,
        X: float,
        Y: float,
        Z: float,
        poses: np.ndarray,
        dx: np.ndarray,
        dy: np.ndarray,
        heading: float = 0.0,
    ) -> SearchResult:
        """Score every grid point (X + dx, Y + dy, pose) against ``edges`` (E, 5).

        The best one wins.
        """
        start = time.perf_counter()
        poses = np.asarray(poses, float)
        gx, gy = np.meshgrid(np.asarray(dx, float), np.asarray(dy, float), indexing='ij')
        offsets = np.stack([gx.ravel(), np.zeros(gx.size), gy.ravel()], 1)  # world (x, depth, z)
        margin = self._pixel_reach(X, Y, Z, offsets)
        curve = np.zeros(len(poses))
        best = (-1.0, 0, 0)
        rendered = self.renderings
        centre = np.array([X, Y, Z])
        for k, pose in enumerate(poses):  # at most one rendering per pose value
            reference, contours = self.reusable_contours(centre, pose, heading)
            if len(contours) == 0 or len(edges) == 0:
                continue
            moved = offsets + (centre - reference)[[0, 2, 1]]  # (X, Y, Z) -> world (x, depth, z)
            a, b = contours.project(self.camera, moved)
            contour, edge = candidate_edges(
                a[len(a) // 2], b[len(b) // 2], edges, margin, self.params
            )
            scores = similarity(a, b, edges, contour, edge, self.params)
            i = int(np.argmax(scores))
            curve[k] = scores[i]
            if scores[i] > best[0]:
                best = (float(scores[i]), k, i)
        s, k, i = best
        return SearchResult(
            X + offsets[i, 0],
            Y + offsets[i, 2],
            float(poses[k]),
            max(s, 0.0),
            poses,
            curve,
            len(poses) * len(offsets),
            self.renderings - rendered,
            time.perf_counter() - start,
        )

    def _pixel_reach(self, X: float, Y: float, Z: float, offsets: np.ndarray) -> float:
        """Largest image displacement (px) of the pelvis over the grid's offsets."""
        centre = np.array([X, Z, Y + 1.0])
        uv = self.camera.project(centre + offsets)
        return float(np.nanmax(np.linalg.norm(uv - self.camera.project(centre), axis=1))) + 1.0


def grid_offsets(half: float, step: float) -> np.ndarray:
    """Offsets -half..half in ``step``s, an odd count centred on 0 (at least 1 point)."""
    n = max(int(round(half / step)), 0)
    return step * np.arange(-n, n + 1)
