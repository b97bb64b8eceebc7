"""Active viewpoint selection (Kakadiaris & Metaxas §4).

Which cameras may update which part at frame t.

Per part i and camera k, from the pose predicted for frame t (and the posterior of t-1 for the
motion):

- the visibility index VI(i, k) = visible projected area / projected area with
  occlusions ignored, counted on the renderer's label image at a reduced
  resolution (§4; §5 counts the same pixels per part colour);
- the observability: the predicted image displacement, between t-1 and t, of the
  part's visible occluding-contour nodes, combined as the paper's
  ``|| sum_j dx_j ||`` (§4) or, as an option, ``sum_j || dx_j ||``;
- the assignment: the cameras with VI >= threshold (§4: 0.2), ranked by
  observability (ties by VI), at most ``max_cameras_per_part`` (0: all); a part that no
  camera sees is unobserved, so the tracker only predicts it.

The occluding-contour nodes of an elliptic cylinder are its two contour generators (side lines
whose normal is perpendicular to the viewing ray, sampled along the axis) and the rim nodes of its
end caps that lie on the silhouette (one of the two faces meeting there is seen, the other not).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import time
from typing import cast

import numpy as np

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import Rendering, render_labels

NORMS = ('norm_of_sum', 'sum_of_norms')
MODE_PREDICTED = 'predicted'
MODE_ALL_CAMERAS = 'all_cameras'


MAX_CAMERAS = 64  # most cameras per part a setting may ask for


@dataclass(frozen=True)
class SelectionSettings:
    """The selector's tunables (the node's parameters), validated on construction."""

    vi_threshold: float = (
        0.0  # part i visible from camera k when VI(i, k) >= this (§4: 0.2; 0: in view)
    )
    max_cameras_per_part: int = (
        0  # cameras kept per part, best observability first (0: every visible one)
    )
    render_scale: float = 0.25  # label images at this fraction of the camera resolution
    observability_norm: str = 'norm_of_sum'  # §4's || sum dx ||, or 'sum_of_norms'
    camera_timeout_s: float = 0.5  # a camera silent for longer (in stamps) is excluded
    contour_spacing_m: float = 0.02  # spacing of the contour-generator nodes along a part's axis
    rim_nodes: int = 24  # nodes around each end-cap rim

    def __post_init__(self) -> None:
        """Refuse values outside their ranges with a one-line reason."""
        problems = []
        if not 0.0 <= self.vi_threshold <= 1.0:
            problems.append(f'vi_threshold={self.vi_threshold} is outside [0, 1]')
        if (
            not 0 <= int(self.max_cameras_per_part) <= MAX_CAMERAS
            or int(self.max_cameras_per_part) != self.max_cameras_per_part
        ):
            problems.append(
                f'max_cameras_per_part={self.max_cameras_per_part} is not an integer in [0, '
                f'{MAX_CAMERAS}]'
            )
        if not 0.05 <= self.render_scale <= 1.0:
            problems.append(f'render_scale={self.render_scale} is outside [0.05, 1]')
        if self.observability_norm not in NORMS:
            problems.append(
                f'observability_norm={self.observability_norm!r} is not one of {", ".join(NORMS)}'
            )
        if not self.camera_timeout_s > 0.0:
            problems.append(f'camera_timeout_s={self.camera_timeout_s} must be positive')
        if not self.contour_spacing_m > 0.0 or self.rim_nodes < 3:
            problems.append('contour_spacing_m must be positive and rim_nodes at least 3')
        if problems:
            raise ValueError('; '.join(problems))


# ------------------------------------------------------------------ result
@dataclass
class Assignment:
    """Per part (rows, PART_NAMES order) and camera (columns).

    VI, observability, selection; one frame.
    """

    cameras: list[str]
    vi: np.ndarray  # (P, K) visibility index, NaN when not computed (dead camera, no posterior)
    observability: (
        np.ndarray
    )  # (P, K) norm of the predicted contour motion, pixels; NaN when not computed
    selected: np.ndarray  # (P, K) bool: camera k may update part i
    observed: (
        np.ndarray
    )  # (P,) bool: False = no camera sees the part, the tracker only predicts it
    alive: np.ndarray  # (K,) bool: camera within its timeout
    mode: str = (
        MODE_PREDICTED  # 'predicted' (from the posterior) or 'all_cameras' (no posterior yet)
    )
    rank: np.ndarray | None = None  # (P, K) int: 0 = best selected camera, -1 = not selected

    def __post_init__(self) -> None:
        """Fill the ranking from observability (then VI, then camera order) when not given."""
        if self.rank is None:
            self.rank = rank_selected(self.selected, self.observability, self.vi)

    def cameras_for(self, part_index: int) -> list[str]:
        """Return the cameras selected for a part, best first."""
        if self.rank is None:  # never: __post_init__ fills it
            raise ValueError('Assignment.rank is None')
        row = self.rank[part_index]
        order = np.argsort(np.where(row < 0, len(self.cameras), row), kind='stable')
        return [self.cameras[k] for k in order if row[k] >= 0]

    def masks(self) -> dict[str, np.ndarray]:
        """Camera -> (P,) bool mask of the parts it may update (what the tracker's step takes)."""
        return {cam: self.selected[:, k].copy() for k, cam in enumerate(self.cameras)}

    @classmethod
    def all_cameras(
        cls,
        cameras: list[str],
        alive: dict[str, bool] | None = None,
        n_parts: int = len(PART_NAMES),
    ) -> 'Assignment':
        """Before the tracker has a posterior: every live camera for every part (DESIGN.md)."""
        live = np.array(
            [True if alive is None else bool(alive.get(c, True)) for c in cameras], bool
        )
        shape = (n_parts, len(cameras))
        selected = np.broadcast_to(live, shape).copy()
        return cls(
            list(cameras),
            np.full(shape, np.nan),
            np.full(shape, np.nan),
            selected,
            cast(np.ndarray, selected.any(axis=1)),  # the stubs type a reduction as maybe scalar
            live,
            MODE_ALL_CAMERAS,
        )


def rank_selected(selected: np.ndarray, observability: np.ndarray, vi: np.ndarray) -> np.ndarray:
    """Rank (P, K) of the selected cameras per part.

    Observability descending, then VI, then camera order.
    """
    obs = np.where(np.isfinite(observability), observability, -np.inf)
    vis = np.where(np.isfinite(vi), vi, -np.inf)
    k = selected.shape[1]
    rank = np.full(selected.shape, -1, int)
    for i in range(selected.shape[0]):
        order = np.lexsort((np.arange(k), -vis[i], -obs[i]))  # last key is the primary one
        order = order[selected[i, order]]
        rank[i, order] = np.arange(len(order))
    return rank


# ------------------------------------------------------------ the science
def visibility_index(rendering: Rendering, n_parts: int = len(PART_NAMES)) -> np.ndarray:
    """VI per part (P,).

    Visible / unoccluded projected area (§4), 0 where the part is not in the image.
    """
    visible = rendering.visible_area(n_parts).astype(float)
    total = np.asarray(rendering.unoccluded_area[:n_parts], float)
    return np.divide(visible, total, out=np.zeros(n_parts), where=total > 0)


@dataclass
class ContourModel:
    """Part-frame samples from which each camera's occluding-contour nodes are picked.

    Built once per body.
    """

    semi_axes: np.ndarray  # (P, 2)
    lengths: np.ndarray  # (P,)
    side_part: np.ndarray  # (S,) part of each sample height on a contour generator
    side_z: np.ndarray  # (S,) height along the axis, m
    rim_part: np.ndarray  # (R,) part of each rim node
    rim_points: np.ndarray  # (R, 3) part-frame rim points
    rim_side_normal: (
        np.ndarray
    )  # (R, 3) outward side normal at the rim node (part frame, unnormalised)
    rim_cap_sign: np.ndarray  # (R,) -1 proximal cap (normal -z), +1 distal cap (normal +z)

    @classmethod
    def from_body(cls, body: Body, spacing: float = 0.02, rim_nodes: int = 24) -> 'ContourModel':
        """Return the contour model of ``body``.

        Generator heights every ``spacing`` m (cell centres) and ``rim_nodes`` around each cap rim.
        """
        counts = np.maximum(np.ceil(body.lengths / spacing).astype(int), 3)
        side_part = np.repeat(np.arange(len(body.lengths)), counts)
        starts = np.repeat(np.cumsum(counts) - counts, counts)
        cell = np.arange(len(side_part)) - starts
        side_z = (cell + 0.5) / counts[side_part] * body.lengths[side_part]
        theta = np.linspace(0.0, 2 * np.pi, rim_nodes, endpoint=False)
        n_parts = len(body.lengths)
        rim_part = np.repeat(np.arange(n_parts), 2 * rim_nodes)
        sign = np.tile(np.repeat([-1.0, 1.0], rim_nodes), n_parts)
        th = np.tile(theta, 2 * n_parts)
        a, b = body.semi_axes[rim_part, 0], body.semi_axes[rim_part, 1]
        z = np.where(sign > 0, body.lengths[rim_part], 0.0)
        rim_points = np.stack([a * np.cos(th), b * np.sin(th), z], -1)
        rim_normal = np.stack([np.cos(th) / a, np.sin(th) / b, np.zeros_like(th)], -1)
        return cls(
            body.semi_axes.copy(),
            body.lengths.copy(),
            side_part,
            side_z,
            rim_part,
            rim_points,
            rim_normal,
            sign,
        )

    def contour_nodes(self, centre_local: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Occluding-contour nodes for a camera centre in every part's frame (P, 3).

        Parts, points (C, 3), cap (C,).

        ``cap`` is 0 for a node on a contour generator, -1 / +1 for a proximal / distal rim node.
        """
        # side: n(theta) . (p(theta) - c) = 1 - rho cos(theta - phi) = 0 on the two contour
        # generators
        a, b = self.semi_axes[:, 0], self.semi_axes[:, 1]
        ux, uy = centre_local[:, 0] / a, centre_local[:, 1] / b
        rho = np.hypot(ux, uy)
        with np.errstate(invalid='ignore', divide='ignore'):
            half = np.where(rho > 1.0, np.arccos(np.clip(1.0 / rho, -1.0, 1.0)), np.nan)
        phi = np.arctan2(uy, ux)
        generators = np.stack([phi + half, phi - half], -1)  # (P, 2), NaN: camera inside
        theta = generators[self.side_part].T.ravel()  # (2S,)
        part = np.tile(self.side_part, 2)
        z = np.tile(self.side_z, 2)
        ok = np.isfinite(theta)
        side = np.stack([a[part] * np.cos(theta), b[part] * np.sin(theta), z], -1)[ok]
        # rims: on the silhouette when exactly one of the side and the cap faces the camera
        view = self.rim_points - centre_local[self.rim_part]
        facing_side = np.einsum('ri,ri->r', self.rim_side_normal, view)
        facing_cap = self.rim_cap_sign * view[:, 2]
        rim = facing_side * facing_cap <= 0.0
        return (
            np.concatenate([part[ok], self.rim_part[rim]]),
            np.concatenate([side, self.rim_points[rim]]),
            np.concatenate([np.zeros(len(side)), self.rim_cap_sign[rim]]),
        )


def occluding_contour(
    model: ContourModel,
    camera: Camera,
    rotations: np.ndarray,
    origins: np.ndarray,
    rendering: Rendering,
    scale: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Return the visible occluding-contour nodes P_i of every part (§4).

    Parts (C,) and part-frame points (C, 3).

    A node lies on its part's silhouette edge, so its own pixel cannot tell whether something
    covers it.  It is tested one label-image pixel inside instead (towards the axis, and along it
    for a rim node): that point projects inside the part's own silhouette (a convex part), so a
    node is visible when the label there is its own part (or nothing), and hidden by any other
    label.
    """
    centre_local = np.einsum('pji,pj->pi', rotations, camera.centre - origins)  # R^T (c - o)
    part, local, cap = model.contour_nodes(centre_local)
    r, o = rotations[part], origins[part]
    pc = camera.world_to_camera(np.einsum('cij,cj->ci', r, local) + o)
    uv = camera.project_camera(pc)
    pixel_m = np.abs(pc[:, 2]) / (camera.K[0, 0] * scale)  # one label pixel at the node's depth
    radius = np.maximum(np.hypot(local[:, 0], local[:, 1]), 1e-9)
    inward = local.copy()
    inward[:, :2] *= (1.0 - np.minimum(pixel_m / radius, 0.5))[:, None]
    inward[:, 2] -= cap * np.minimum(pixel_m, 0.5 * model.lengths[part])
    uv_in = camera.project(np.einsum('cij,cj->ci', r, inward) + o)
    height, width = rendering.label.shape
    col = np.floor((np.nan_to_num(uv_in[:, 0], nan=-1.0) + 0.5) * scale).astype(int)
    row = np.floor((np.nan_to_num(uv_in[:, 1], nan=-1.0) + 0.5) * scale).astype(int)
    in_view = (
        np.isfinite(uv).all(axis=1)
        & (uv[:, 0] >= -0.5)
        & (uv[:, 0] <= camera.width - 0.5)
        & (uv[:, 1] >= -0.5)
        & (uv[:, 1] <= camera.height - 0.5)
    )
    sampled = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    label = rendering.label[np.where(sampled, row, 0), np.where(sampled, col, 0)].astype(int)
    keep = in_view & (~sampled | (label == 0) | (label == part + 1))
    return part[keep], local[keep]


def observability(
    camera: Camera,
    part: np.ndarray,
    local: np.ndarray,
    prev: tuple[np.ndarray, np.ndarray],
    pred: tuple[np.ndarray, np.ndarray],
    n_parts: int,
    norm: str = 'norm_of_sum',
) -> np.ndarray:
    """Per part (P,).

    Image motion of its contour nodes from t-1 to t, || sum_j dx_j || (§4) or sum_j ||dx_j||.
    """
    (r0, o0), (r1, o1) = prev, pred
    x0 = camera.project(np.einsum('cij,cj->ci', r0[part], local) + o0[part])
    x1 = camera.project(np.einsum('cij,cj->ci', r1[part], local) + o1[part])
    dx = np.nan_to_num(x1 - x0)  # the paper's  I-x-dot  per node
    if norm == 'norm_of_sum':  # §4: || sum_{j in P_i} dx_j ||
        sx = np.bincount(part, weights=dx[:, 0], minlength=n_parts)
        sy = np.bincount(part, weights=dx[:, 1], minlength=n_parts)
        return np.hypot(sx, sy)
    if norm == 'sum_of_norms':  # option: sum_{j in P_i} || dx_j ||
        return np.bincount(part, weights=np.hypot(dx[:, 0], dx[:, 1]), minlength=n_parts)
    raise ValueError(f'unknown observability norm {norm!r}; known: {", ".join(NORMS)}')


def assignment(
    vi: np.ndarray, obs: np.ndarray, alive: np.ndarray, threshold: float, max_cameras: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """§4 selection.

    Visible (VI >= threshold, alive) cameras ranked by observability, at most ``max_cameras`` (0:
    all).

    Returns selected (P, K), observed (P,) and rank (P, K); a visible part always keeps its best
    camera.
    """
    visible = (np.nan_to_num(vi, nan=-1.0) >= threshold) & alive[None, :]
    rank = rank_selected(visible, obs, vi)
    selected = (rank >= 0) & ((rank < max_cameras) | (max_cameras <= 0))
    return selected, visible.any(axis=1), np.where(selected, rank, -1)


# ------------------------------------------------------------ the selector
class CameraSelector:
    """Computes the per-frame :class:`Assignment` for a body and a calibrated rig."""

    def __init__(
        self, body: Body, cameras: list[Camera], settings: SelectionSettings | None = None
    ) -> None:
        self.body = body
        self.cameras = list(cameras)
        self.names = [c.name for c in self.cameras]
        self.settings = settings or SelectionSettings()
        self.contour_model = ContourModel.from_body(
            body, self.settings.contour_spacing_m, self.settings.rim_nodes
        )
        self._views = [
            c.scaled(self.settings.render_scale) for c in self.cameras
        ]  # label-image cameras

    def assign(
        self, q_prev: np.ndarray, q_pred: np.ndarray, alive: dict[str, bool] | None = None
    ) -> Assignment:
        """Return the assignment for frame t.

        From the posterior coordinates of t-1 and the prediction for t.
        """
        s = self.settings
        n_parts = len(self.body.lengths)
        rotations, origins = self.body.forward_kinematics(np.stack([q_prev, q_pred]))
        prev, pred = (rotations[0], origins[0]), (rotations[1], origins[1])
        live = np.array(
            [True if alive is None else bool(alive.get(n, True)) for n in self.names], bool
        )
        vi = np.full((n_parts, len(self.cameras)), np.nan)
        obs = np.full_like(vi, np.nan)
        for k, cam in enumerate(self.cameras):
            if not live[k]:
                continue
            rendering = render_labels(
                cam,
                pred[0],
                pred[1],
                self.body.semi_axes,
                self.body.lengths,
                s.render_scale,
                self._views[k],
            )
            vi[:, k] = visibility_index(rendering, n_parts)
            part, local = occluding_contour(
                self.contour_model, cam, pred[0], pred[1], rendering, s.render_scale
            )
            obs[:, k] = observability(cam, part, local, prev, pred, n_parts, s.observability_norm)
        selected, observed, rank = assignment(
            vi, obs, live, s.vi_threshold, int(s.max_cameras_per_part)
        )
        return Assignment(
            list(self.names), vi, obs, selected, observed, live, MODE_PREDICTED, rank
        )


@dataclass
class CameraLiveness:
    """Which cameras are alive at a frame stamp.

    The camera is heard of and its contour_node delivers.

    - heard of: the newest camera_info or contours stamp is within the timeout of the frame
      (stamps, not
      arrival times, so a bag replayed at any rate behaves alike; either stream, as one of them may
      lag
      in a loaded process; the clock starts at the first frame, so a camera never heard of drops
      out
      once the timeout has passed);
    - contours (``require_contours``): the contour_node is gone once its contours stopped arriving
      both
      for more than the timeout of camera_info stamps and for more than ``contours_timeout_s`` of
      wall
      time.  A contour_node that lags behind the cameras, or is starved of CPU for a moment, still
      delivers, so it is not taken for dead; without ``require_contours`` being heard of is enough
      (the
      selector run without contour nodes).

    """

    cameras: list[str]
    timeout_s: float
    require_contours: bool = True
    contours_timeout_s: float = 2.0
    newest_ns: dict[tuple[str, str], int] = field(default_factory=dict)
    first_frame_ns: int | None = None
    first_wall: float | None = None
    # camera -> (wall time of the last contours, newest camera_info stamp then)
    contours_arrival: dict[str, tuple[float, int]] = field(default_factory=dict)

    SOURCES = ('camera_info', 'contours')

    def seen(self, camera: str, stamp_ns: int, source: str, wall: float | None = None) -> None:
        """Note that a message of ``camera`` from ``source`` with this header stamp arrived.

        ``source`` is camera_info or contours; it arrived at monotonic ``wall`` time, now by
        default.
        """
        if source not in self.SOURCES:
            raise ValueError(
                f'unknown liveness source {source!r}; one of {", ".join(self.SOURCES)}'
            )
        if camera not in self.cameras:
            return
        key = (camera, source)
        self.newest_ns[key] = max(self.newest_ns.get(key, stamp_ns), stamp_ns)
        if source == 'contours':
            info = self.newest_ns.get((camera, 'camera_info'), stamp_ns)
            self.contours_arrival[camera] = (
                time.monotonic() if wall is None else wall,
                max(info, stamp_ns),
            )

    def alive(self, frame_ns: int, wall: float | None = None) -> dict[str, bool]:
        """Camera -> alive at frame ``frame_ns``.

        Judged at monotonic ``wall`` time, now by default.
        """
        wall = time.monotonic() if wall is None else wall
        if self.first_frame_ns is None or self.first_wall is None:  # both set here, together
            self.first_frame_ns, self.first_wall = frame_ns, wall
        first_ns, first_wall = self.first_frame_ns, self.first_wall
        limit = int(round(self.timeout_s * 1e9))

        def recent(camera: str, source: str) -> bool:
            return frame_ns - self.newest_ns.get((camera, source), first_ns) <= limit

        def delivering(camera: str) -> bool:
            since_wall, since_ns = self.contours_arrival.get(camera, (first_wall, first_ns))
            return frame_ns - since_ns <= limit or wall - since_wall <= self.contours_timeout_s

        heard = {c: recent(c, 'camera_info') or recent(c, 'contours') for c in self.cameras}
        if not self.require_contours:
            return heard
        return {c: heard[c] and delivering(c) for c in self.cameras}

    def reset(self) -> None:
        """Forget every stamp (time jumped backwards)."""
        self.newest_ns.clear()
        self.contours_arrival.clear()
        self.first_frame_ns = self.first_wall = None
