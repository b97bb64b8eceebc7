"""The articulated multi-camera tracker (Kakadiaris & Metaxas §2-4): one frame in, one posterior out.

Per frame: predict with the shared motion model; per camera, Step 1 of the force
assignment on its contour samples; then an iterated EKF update whose
measurements, relinearised at every iterate, are each matched sample's image
force along the contour normal (eq. 14: the component across the contour, the
one a contour can measure) and the normal force k_z - n (eq. 15) of side nodes,
both through the Jacobian L (eq. 9, 16).  A sample only acts on a part whose
camera the selector chose for it.  No contour anywhere, or an inconsistent
filter for several frames, means tracking is lost: it is reported and the pose
re-initialised from the silhouettes, never published as if it were tracked.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from memo_ros.core.body import PART_NAMES, Body
from memo_ros.core.camera import Camera
from memo_ros.core.correspondence import assign_forces, contour_rays, silhouette_candidates
from memo_ros.core.ekf import ArticulatedEKF, Measurements, UpdateReport
from memo_ros.core.kinematic_jacobian import chain_axes, chain_membership, normal_jacobian, point_jacobian
from memo_ros.core.model_nodes import model_nodes
from memo_ros.core.motion import ConstantVelocity, ProcessNoise, coordinate_rates
from memo_ros.core.render import render
from memo_ros.core.rotations import rot_z, matrix_to_rotvec

WAITING, TRACKING, LOST = 'waiting', 'tracking', 'lost'

# anatomical ranges of the hinge coordinates, rad (elbows and knees cannot hyperextend)
JOINT_LIMITS: dict[str, tuple[float, float]] = {
    'elbow_l_y': (0.0, 2.6), 'elbow_r_y': (0.0, 2.6),
    'wrist_l_y': (-1.3, 1.3), 'wrist_r_y': (-1.3, 1.3), 'wrist_l_x': (-0.6, 0.6), 'wrist_r_x': (-0.6, 0.6),
    'knee_l_y': (-2.6, 0.0), 'knee_r_y': (-2.6, 0.0),
    'ankle_l_y': (-0.9, 0.9), 'ankle_r_y': (-0.9, 0.9),
}


@dataclass
class TrackerSettings:
    """Noises, gates and iteration counts of the tracker (the node's parameters)."""

    sigma_px: float = 2.0              # image force noise across the contour, pixels
    sigma_rim_px: float = 6.0          # the same across a part's end, where contour smoothing rounds the tips
    sigma_normal: float = 0.15         # normal force noise (unit vectors); 0 switches eq. 15 off
    search_px: float = 25.0            # largest image distance of a sample to its node
    gate_sigma: float = 4.0            # Mahalanobis gate on each measurement's innovation
    iterations: int = 4                # iterated-EKF relinearisations per frame
    render_scale: float = 0.25         # resolution of the silhouette test rendering
    ring_spacing: float = 0.03         # m between node rings along a part
    min_matched_fraction: float = 0.3  # fewer matched samples than this fraction = inconsistent frame
    nis_limit: float = 30.0            # mean NIS above this = inconsistent frame
    lost_after: int = 5                # inconsistent (or empty) frames in a row before tracking is lost
    init_sigma_translation: float = 0.05
    init_sigma_rotation: float = 0.1
    init_iterations: int = 15
    init_headings: int = 8
    process_noise: ProcessNoise = field(default_factory=ProcessNoise)


@dataclass
class FrameResult:
    """The tracker's answer for one frame."""

    stamp_ns: int
    status: str                        # waiting, tracking or lost
    q: np.ndarray | None = None
    qdot: np.ndarray | None = None     # time derivatives of q (JointState velocities)
    covariance: np.ndarray | None = None
    rotations: np.ndarray | None = None
    origins: np.ndarray | None = None
    samples: int = 0                   # contour samples in
    matched: int = 0                   # tied to a node of a selected camera
    unselected: int = 0                # tied to a part whose camera was not selected
    report: UpdateReport = field(default_factory=UpdateReport)
    initialised: bool = False          # this frame (re)started the track
    seconds: float = 0.0
    reason: str = ''


class ArticulatedTracker:
    """Tracks the body in a rig of calibrated cameras from their occluding contours."""

    def __init__(self, body: Body, cameras: list[Camera], settings: TrackerSettings | None = None,
                 initial_pose: np.ndarray | None = None) -> None:
        self.body = body
        self.cameras = {c.name: c for c in cameras}
        self.settings = settings or TrackerSettings()
        self.initial_pose = None if initial_pose is None else np.asarray(initial_pose, float)
        self.model = ConstantVelocity(body, self.settings.process_noise)
        self.ekf = ArticulatedEKF(self.model)
        self.nodes = model_nodes(body, ring_spacing=self.settings.ring_spacing)
        self.affects = chain_membership(body)
        self.limit_index = np.array([body.coordinate_index(n) for n in JOINT_LIMITS], int)
        self.limit_low = np.array([lo for lo, _ in JOINT_LIMITS.values()])
        self.limit_high = np.array([hi for _, hi in JOINT_LIMITS.values()])
        self.reset()

    # ------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the track: the next frame with contours initialises again."""
        self.status = WAITING
        self.stamp_ns: int | None = None
        self.bad_frames = 0
        self.pending_pose: np.ndarray | None = self.initial_pose

    def set_pose(self, q: np.ndarray) -> None:
        """Use ``q`` (and zero velocity) at the next frame, like robot_localization's set_pose."""
        q = np.asarray(q, float)
        if q.shape != (self.body.n_coordinates,) or not np.all(np.isfinite(q)):
            raise ValueError(f'a pose needs {self.body.n_coordinates} finite coordinates')
        self.reset()
        self.pending_pose = q

    # ------------------------------------------------------------ frames
    def step(self, stamp_ns: int, contours: dict[str, np.ndarray],
             selected: dict[str, np.ndarray] | None = None) -> FrameResult:
        """Track one frame: contour tables per camera; ``selected`` maps a camera to its (P,) part mask."""
        start = time.perf_counter()
        contours = {c: t for c, t in contours.items() if c in self.cameras and len(t)}
        samples = sum(len(t) for t in contours.values())
        if not samples:
            return self._no_body(stamp_ns, start)
        rays = {c: contour_rays(self.cameras[c], t) for c, t in contours.items()}
        masks = {c: (np.ones(len(PART_NAMES), bool) if selected is None or c not in selected
                     else np.asarray(selected[c], bool)) for c in contours}
        initialised = False
        if self.status != TRACKING:
            self._initialise(stamp_ns, contours, rays)
            initialised = True
        else:
            self.ekf.predict((stamp_ns - self.stamp_ns) * 1e-9)
        labels = self._render_depths(self.ekf.q, contours)
        measure = self._measurement_function(contours, rays, masks, labels)
        report = self.ekf.update(measure, self.settings.iterations, self.settings.gate_sigma)
        self._enforce_limits()
        self.stamp_ns = stamp_ns
        matched, unselected = self._last_counts
        consistent = (report.used >= self.settings.min_matched_fraction * samples
                      and not report.nis > self.settings.nis_limit)
        self.bad_frames = 0 if consistent else self.bad_frames + 1
        if self.bad_frames >= self.settings.lost_after:
            self.reset()
            self.status = LOST
            return FrameResult(stamp_ns, LOST, samples=samples, matched=matched, report=report,
                               seconds=time.perf_counter() - start,
                               reason=f'filter inconsistent for {self.settings.lost_after} frames '
                                      f'(NIS {report.nis:.1f}, {report.used}/{samples} samples used)')
        self.status = TRACKING
        rotations, origins = self.body.forward_kinematics(self.ekf.q)
        return FrameResult(stamp_ns, TRACKING, self.ekf.q.copy(),
                           coordinate_rates(self.ekf.q, self.ekf.v, self.model.groups), self.ekf.P.copy(),
                           rotations, origins, samples, matched, unselected, report, initialised,
                           time.perf_counter() - start, '' if consistent else 'inconsistent frame')

    def _enforce_limits(self) -> None:
        """Project the estimate onto the joint ranges (the projection method of constrained Kalman filtering)."""
        q = self.ekf.q[self.limit_index]
        clipped = np.clip(q, self.limit_low, self.limit_high)
        hit = clipped != q
        if hit.any():
            self.ekf.q[self.limit_index] = clipped
            v = self.ekf.v[self.limit_index]
            self.ekf.v[self.limit_index] = np.where(hit, 0.0, v)

    def _no_body(self, stamp_ns: int, start: float) -> FrameResult:
        """No contour from any camera: predict while the track is young, then lose it."""
        if self.status != TRACKING:
            return FrameResult(stamp_ns, self.status, seconds=time.perf_counter() - start,
                               reason='no contours from any camera')
        self.bad_frames += 1
        if self.bad_frames >= self.settings.lost_after:
            self.reset()
            self.status = LOST
            return FrameResult(stamp_ns, LOST, seconds=time.perf_counter() - start,
                               reason=f'no camera saw the body for {self.settings.lost_after} frames')
        self.ekf.predict((stamp_ns - self.stamp_ns) * 1e-9)
        self.stamp_ns = stamp_ns
        rotations, origins = self.body.forward_kinematics(self.ekf.q)
        return FrameResult(stamp_ns, TRACKING, self.ekf.q.copy(),
                           coordinate_rates(self.ekf.q, self.ekf.v, self.model.groups), self.ekf.P.copy(),
                           rotations, origins, seconds=time.perf_counter() - start,
                           reason='no contours: predicted only')

    # ------------------------------------------------------------ measurement model
    def _render_depths(self, q: np.ndarray, cameras) -> dict[str, np.ndarray]:
        rotations, origins = self.body.forward_kinematics(q)
        scale = self.settings.render_scale
        return {c: render(self.cameras[c], rotations, origins, self.body.semi_axes, self.body.lengths,
                          scale=scale).depth for c in cameras}

    def _measurement_function(self, contours, rays, masks, labels):
        """measure(q) -> Measurements: the forces of eq. 14-15 linearised at q (Jacobians of eq. 9, 16)."""
        s = self.settings
        n = self.body.n_coordinates
        self._last_counts = (0, 0)

        def measure(q: np.ndarray) -> Measurements:
            rotations, origins = self.body.forward_kinematics(q)
            chain = chain_axes(self.body, q, rotations, origins, self.affects)
            rows_H, rows_r, rows_s = [], [], []
            matched = unselected = 0
            for cam_name in contours:
                cam = self.cameras[cam_name]
                cand = silhouette_candidates(cam, self.nodes, rotations, origins, labels[cam_name], s.render_scale)
                m = assign_forces(rays[cam_name], cand, self.nodes.epsilon, s.search_px)
                use = masks[cam_name][cand.part[m.node]]
                unselected += int((~use).sum())
                sample, node = m.sample[use], m.node[use]
                matched += len(sample)
                if not len(sample):
                    continue
                parts = cand.part[node]
                points = cand.points[node]
                uv, J_proj = cam.project_with_jacobian(points)
                L = point_jacobian(chain, parts, points)                      # eq. 9: L
                Lp = J_proj @ L                                               # eq. 9: L_p = H R^-1 L
                m_out = rays[cam_name].outward[sample]
                rows_H.append(np.einsum('ni,nij->nj', m_out, Lp))
                rows_r.append(np.einsum('ni,ni->n', m_out, rays[cam_name].uv[sample] - uv))   # eq. 14
                side = ~cand.rim[node]
                rows_s.append(np.where(side, s.sigma_px, s.sigma_rim_px))
                if s.sigma_normal > 0 and side.any():
                    normals = cand.normal[node][side]
                    Jn = normal_jacobian(chain, parts[side], normals, rotations[parts[side]][:, :, 2])
                    rows_H.append(Jn.reshape(-1, n))
                    rows_r.append((rays[cam_name].k[sample][side] - normals).reshape(-1))      # eq. 15
                    rows_s.append(np.full(3 * int(side.sum()), s.sigma_normal))
            self._last_counts = (matched, unselected)
            if not rows_r:
                return Measurements.empty(n)
            return Measurements(np.concatenate(rows_H), np.concatenate(rows_r), np.concatenate(rows_s))

        return measure

    # ------------------------------------------------------------ initialisation
    def _initialise(self, stamp_ns: int, contours, rays) -> None:
        """Start from the given pose, or from the silhouettes: root from the rays through their centres,
        a standing posture at the best of several headings, refined by the update itself."""
        s = self.settings
        sigma_q = np.full(self.body.n_coordinates, s.init_sigma_rotation)
        sigma_q[:3] = s.init_sigma_translation
        sigma_v = np.full(self.body.n_coordinates, 0.5)
        sigma_v[:3] = 0.3
        if self.pending_pose is not None:
            self.ekf.initialize(self.pending_pose, None, sigma_q, sigma_v)
            return
        centre = triangulate_centre([self.cameras[c] for c in contours], [contours[c] for c in contours])
        neutral = self.body.neutral()
        best = None
        for k in range(max(s.init_headings, 1)):
            q = neutral.copy()
            heading = 2 * np.pi * k / max(s.init_headings, 1)
            q[3:6] = matrix_to_rotvec(rot_z(heading))
            if centre is not None:
                q[0:2] = centre[0:2]
            self.ekf.initialize(q, None, np.where(np.arange(len(q)) < 3, 0.3, 0.5), sigma_v)
            masks = {c: np.ones(len(PART_NAMES), bool) for c in contours}
            labels = self._render_depths(q, contours)
            report = self.ekf.update(self._measurement_function(contours, rays, masks, labels),
                                     s.init_iterations, gate=1e6)
            score = (self._last_counts[0], -report.nis if np.isfinite(report.nis) else -np.inf)
            if best is None or score > best[0]:
                best = (score, self.ekf.q.copy())
        self.ekf.initialize(best[1], None, sigma_q, sigma_v)


def triangulate_centre(cameras: list[Camera], tables: list[np.ndarray]) -> np.ndarray | None:
    """Least-squares meeting point of the rays through each camera's contour centroid (None with < 2 cameras)."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    used = 0
    for cam, table in zip(cameras, tables):
        if not len(table):
            continue
        d = cam.pixel_rays(np.array([table['x'].mean()]), np.array([table['y'].mean()]))[0]
        proj = np.eye(3) - np.outer(d, d)
        A += proj
        b += proj @ np.asarray(cam.t_world_cam, float)
        used += 1
    if used < 2:
        return None
    return np.linalg.solve(A, b)
