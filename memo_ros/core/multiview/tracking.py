"""The articulated multi-camera tracker (Kakadiaris & Metaxas §2-4).

One frame in, one posterior out.

Per frame: predict with the shared motion model; per camera, Step 1 of the force assignment on its
contour samples; then an iterated EKF update whose measurements, relinearised at every iterate, are
each matched sample's image force along the contour normal (eq. 14: the component across the
contour, the one a contour can measure) and the normal force k_z - n (eq. 15) of side nodes, both
through the Jacobian L (eq. 9, 16).  A sample only acts on a part whose camera the selector chose
for it.  No contour anywhere, or an inconsistent filter for several frames, means tracking is lost:
it is reported and the pose re-initialised from the silhouettes, never published as if it were
tracked.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
import time

import numpy as np

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.rotations import matrix_to_rotvec, rot_z
from memo_ros.core.multiview.anatomy import Anatomy
from memo_ros.core.multiview.correspondence import (
    Candidates,
    Matches,
    assign_forces,
    contour_rays,
    rig_on_outline,
    rig_outline_candidates,
    thinned_samples,
)
from memo_ros.core.multiview.ekf import ArticulatedEKF, Measurements, UpdateReport
from memo_ros.core.multiview.kinematic_jacobian import (
    chain_axes,
    chain_membership,
    normal_jacobian,
    projected_rows,
)
from memo_ros.core.multiview.leg_labels import legs_alike, legs_in_place
from memo_ros.core.multiview.limb_search import (
    LimbPostures,
    limb_postures,
    pair_postures,
    posture_scores,
)
from memo_ros.core.multiview.model_nodes import model_nodes
from memo_ros.core.multiview.motion import (
    ConstantVelocity,
    ProcessNoise,
    coordinate_rates,
)
from memo_ros.core.multiview.proportions import (
    BodyMeter,
    person_silhouettes,
    silhouette_disagreement,
)
from memo_ros.core.multiview.silhouette_hold import outside_pull, silhouette_fields
from memo_ros.core.multiview.travel import PelvisPath, travel_support

WAITING, TRACKING, LOST = 'waiting', 'tracking', 'lost'
LIMB_REFINE_STARTS = 2  # a limb's best postures on the cheap score refined by the update
PAIR_REFINE_STARTS = 2  # a pair's (_search_pairs)
# while tracking, a limb is refined only from a start that already gains this fraction of
# limb_recheck_gain: one that gains less is the limb where the filter has it (a hanging arm is a
# canonical posture), and refining it found the filter's own posture again at 2 updates and 2
# scores a limb (studio-arm: 11 of 11 rechecks, none kept; the Pose2Sim arm found gained 4.8 of 5)
LIMB_RECHECK_START_GAIN = 0.2
LIMB_REFINE_ITERATIONS = 3
LIMB_REFINE_SIGMA = 0.3  # rad, the prior of a refined limb posture (the limb's joints)
LIMB_HOLD_SIGMA = 0.02  # rad or m, the prior of the rest of the body while a limb is refined
TWIN_CHECK_FRAMES = 3  # frames a decided leader is checked against its twin
TRAVEL_LOOK_SUPPORT = 0.5  # a decided leader walking backwards this clearly gets a look
TRAVEL_LOOK_FRAMES = 10  # frames after the last look before walking backwards asks again
REFERENCE_SPACING_PX = (
    2.0  # the sample spacing the noise parameters refer to (contour_node's contour_step)
)


@dataclass
class TrackerSettings:
    """Noises, gates and iteration counts of the tracker (the node's parameters)."""

    sigma_px: float = 1.0  # image force noise across the contour, pixels
    sigma_rim_px: float = (
        3.0  # the same across a part's end, where contour smoothing rounds the tips
    )
    # Cauchy scale of the image forces in units of their noise: a force whose residual at the
    # current iterate is r weighs 1 / (1 + (r / (robust_scale sigma))^2) of its plain weight, so a
    # stretch of contour the pose cannot explain (a segmentation fault: a shoulder whose grey
    # matches the wall cut off the silhouette) stops dragging the pose; 0 = plain least squares
    # (the paper's forces; the default: 1 and 3 changed the Pose2Sim demo for the worse)
    robust_scale: float = 0.0
    sigma_normal: float = 0.0  # normal force noise (unit vectors); 0 switches eq. 15 off (k_z from
    # pixel-staircase tangents is biased; it made the arm worse)
    search_px: float = 25.0  # largest image distance of a sample to its node
    gate_sigma: float = 4.0  # Mahalanobis gate on each measurement's innovation
    iterations: int = 2  # iterated-EKF relinearisations per frame
    outline_probe_px: float = (
        2.0  # a node is on the predicted outline when the body leaves background this far out
    )
    symmetric: bool = (
        False  # every predicted-outline node also pulls on its nearest compatible sample
    )
    contour_smoothing: float = (
        2.0  # the contour node's Gaussian smoothing, px: samples it moved count less
    )
    smoothing_shift: bool = (
        False  # also move samples back by the first-order shift (overshoots at thin tips)
    )
    limit_sigma: float = 0.02  # joint limits as soft pseudo-measurements, rad (0 = no limits)
    # each hip's twist about the thigh's axis (hip_l_z, hip_r_z) measured as 0 with this noise,
    # rad: the elliptic torso hardly shows its heading, and a torso turned with both hips turned
    # back leaves the legs where they were; a twist the feet show still wins (0: off)
    hip_twist_sigma: float = 0.1
    ring_spacing: float = 0.03  # m between node rings along a part
    min_matched_fraction: float = (
        0.3  # fewer matched samples than this fraction = inconsistent frame
    )
    nis_limit: float = 30.0  # mean NIS above this = inconsistent frame
    lost_after: int = 5  # inconsistent (or empty) frames in a row before tracking is lost
    init_sigma_translation: float = 0.05
    init_sigma_rotation: float = 0.1
    init_iterations: int = 15
    init_headings: int = 8
    init_refits: int = 4  # start candidates (heading or its twin) refitted within the ranges
    hard_limits: bool = True  # every estimate projected into the anatomical ranges (JOINT_LIMITS)
    twin_evidence: float = (
        1.0  # evidence (sigma^2 per sample) that decides leader vs twin; 0: no twin
    )
    twin_memory: float = 0.9  # per-frame factor on the evidence gathered so far
    # evidence (sigma^2 per sample) per unit of the silhouettes' disagreement (the pixels where
    # the model's silhouette and the person's differ, per person pixel, summed over the cameras)
    # the twin contest adds to the contour misfit's: a person the model's shape fits less exactly
    # can fit the turned pose's contours better while its silhouettes say otherwise; 0: off
    twin_silhouette: float = 1.0
    twin_recheck: int = 30  # frames between two looks at the twin once decided (0: only at start)
    twin_max_frames: int = 60  # longest the twin is followed before the better of the two is kept
    # evidence (sigma^2 per sample, with twin_memory) that decides which leg is which: every start
    # also follows the pose with its legs exchanged in place (leg_labels.py) until one labelling
    # fits better by this much, the two agree, or twin_max_frames pass; 0: the start's labelling
    legs_evidence: float = 1.0
    # evidence per frame (sigma^2 per sample) for the pose walking forwards at twice
    # travel_speed or faster; a pose walking backwards gets a look at its twin (0: off)
    travel_evidence: float = 0.5
    travel_speed: float = 0.5  # m/s of the pelvis (over travel.TRAVEL_WINDOW_S) that says nothing
    limb_exchange: float = 0.5  # rad a pair's left-right difference moves before a try exchanged
    exchange_margin: float = 0.05  # sigma^2 per sample the exchanged limbs must fit better by
    recover_margin: float = 0.3  # misfit (sigma^2 / sample) over the usual that starts a search
    limb_search: float = 0.1  # sigma^2 per sample a limb's re-found posture must fit better by at
    # a start (limb_search.py); 0: a start keeps its limbs where the pose put them
    # frames between two searches of the limbs while tracking (0: only at a start): a limb the
    # filter lost (an arm swung up fast) is found again by itself, the rest of the body kept
    limb_recheck: int = 5
    limb_recheck_gain: float = (
        5.0  # px^2 per sample the re-found limb's outline must fit better by
    )
    recover_iterations: int = 5  # relinearisations of each re-search from a broad prior
    # a search again that does not bring the misfit back also poses each pair of limbs together
    # in their canonical postures (a kick followed by the standing leg: _search_pairs), kept if it
    # fits better by this much (sigma^2 per sample) than the pose and the search's own best: a
    # pair moved far from the filter's track needs clear evidence; 0: never
    pair_search: float = 0.5
    # a frame this long (s) after the last tracked one (a live tracker skipped frames behind a
    # slow start or a search) starts from the last pose moved with the silhouettes' centre when
    # that fits its contours better than the constant-velocity guess, and is updated with
    # recover_iterations; 0: always the guess, with the usual iterations
    reacquire_gap: float = 0.25
    recover_memory: float = 0.9  # per-frame factor of the running usual misfit
    hold_sigma_px: float = 2.0  # noise of the silhouette's hold on a node outside it (0: off)
    hold_hull: bool = True  # hold within each camera's convex hull of its contours, not the
    # silhouette itself: a part the segmentation missed inside the person's outline is not pulled
    hold_tolerance_px: float = 2.0  # how far outside the silhouette a node may lie unpulled
    hold_cap_px: float = 4.0  # the largest pull of one node in one iteration, pixels
    # tracked frames after a start over which each of the shoulder width and the upper arms'
    # length is measured in turn (proportions.py), for a body scaled from a template (a real
    # person's); 0: the body's proportions are the person's
    proportion_frames: int = 0
    # contour samples per camera and frame the tracker takes, every k-th of each contour (the
    # noise per sample follows the spacing); 0: all
    samples_per_camera: int = 0
    process_noise: ProcessNoise = field(default_factory=ProcessNoise)


@dataclass
class FrameResult:
    """The tracker's answer for one frame."""

    stamp_ns: int
    status: str  # waiting, tracking or lost
    q: np.ndarray | None = None
    qdot: np.ndarray | None = None  # time derivatives of q (JointState velocities)
    covariance: np.ndarray | None = None
    rotations: np.ndarray | None = None
    origins: np.ndarray | None = None
    samples: int = 0  # contour samples in
    matched: int = 0  # tied to a node of a selected camera
    unselected: int = 0  # tied to a part whose camera was not selected
    report: UpdateReport = field(default_factory=UpdateReport)
    initialised: bool = False  # this frame (re)started the track
    seconds: float = 0.0
    reason: str = ''
    heading_confidence: float = 1.0  # how sure the tracker is that the pose is not its twin, 0.5-1
    undecided: bool = (
        False  # the twin is followed beside the pose: the evidence has not separated them
    )
    twin_swaps: int = 0  # times the twin won and took the pose's place, since the start
    legs_undecided: bool = False  # the legs exchanged in place are followed beside the pose
    leg_swaps: int = (
        0  # times the legs exchanged in place won and took the pose's, since the start
    )
    limb_exchanges: int = 0  # times a pair of limbs fitted better exchanged, since the start
    recoveries: int = 0  # times a re-search from a broad prior fitted better, since the start
    limbs_found: int = 0  # limbs a start or a recheck moved to a posture of the limb search
    searches_deferred: int = 0  # searches put off because a newer frame waited, since the start


class ArticulatedTracker:
    """Tracks the body in a rig of calibrated cameras from their occluding contours."""

    _last_counts: tuple[int, int]  # (matched, unselected) of the last linearisation

    def __init__(
        self,
        body: Body,
        cameras: list[Camera],
        settings: TrackerSettings | None = None,
        initial_pose: np.ndarray | None = None,
    ) -> None:
        self.cameras = {c.name: c for c in cameras}
        self.settings = settings or TrackerSettings()
        self.initial_pose = None if initial_pose is None else np.asarray(initial_pose, float)
        self._use_body(body)
        self.ekf = ArticulatedEKF(self.model)
        self.twin_swaps = 0
        self.leg_swaps = 0
        self.limb_exchanges = 0
        self.recoveries = 0
        self.limbs_found = 0  # limbs a start or a recheck moved (_search_limbs)
        self.searches_deferred = 0  # searches put off because may_search said no (step)
        self.reacquisitions = 0  # frames after a gap started from the moved last pose (step)
        self._may_search: Callable[[], bool] = _always
        self.proportions = (  # the person's shoulder width and upper arms, measured while tracking
            BodyMeter(
                self.settings.proportion_frames,
                lambda b: ArticulatedTracker(
                    b, cameras, replace(self.settings, proportion_frames=0)
                ),
            )
            if self.settings.proportion_frames > 0
            else None
        )
        self._fields_of: dict | None = None  # the contours the silhouette fields were made from
        self._fields: dict = {}
        self._holding = True  # the silhouette holds the body (not during the heading search)
        self.reset()

    # ------------------------------------------------------------ state
    def reset(self, use_initial_pose: bool = True, pose: np.ndarray | None = None) -> None:
        """Forget the track.

        The next frame with contours initialises again, from ``pose`` if given, else from the
        studio's initial pose (a user reset, a bag loop) or, after a lost track, from the
        silhouettes.
        """
        self.status = WAITING
        self.stamp_ns: int | None = None
        self.centre: np.ndarray | None = None  # the silhouettes' centre at the last frame
        self.bad_frames = 0
        self.usual_cost: float | None = None  # running misfit per sample of the track (_recover)
        self.pending_pose: np.ndarray | None = (
            pose if pose is not None else self.initial_pose if use_initial_pose else None
        )
        self.twin_ekf: ArticulatedEKF | None = None  # the leader's twin, while it is followed
        self._start_twin: np.ndarray | None = (
            None  # the start's best twin, from the heading search
        )
        self.evidence = 0.0  # > 0: the leader fits better than its twin (sigma^2 per sample)
        self.twin_check = False  # the twin is followed only to check a decided leader
        self.twin_age = 0
        self.since_twin = 0  # frames since the twin was last followed
        self.look_wanted = False  # a look at the twin is due since an inconsistent frame
        self.legs_ekf: ArticulatedEKF | None = None  # the pose with its legs exchanged in place
        self.leg_evidence = 0.0  # > 0: the leader's legs fit better than those exchanged in place
        self.legs_age = 0
        self.path = PelvisPath()  # the leader's pelvis: the direction of travel (travel.py)
        # frames since each limb was last searched (_recheck_limbs), staggered: one limb a frame
        self.since_limbs = -np.arange(len(self.limb_postures))
        # each pair of limbs' left-right difference when it was last tried exchanged
        self.exchange_tried = {
            pair: self.anatomy.difference(self.pending_pose, pair)
            if self.pending_pose is not None
            else np.zeros(len(limb[0]))
            for pair, limb in self.anatomy.limbs.items()
        }

    def change_body(self, body: Body) -> None:
        """Track on with ``body`` (the same coordinates) from the estimate: a size measured."""
        self._use_body(body)
        self.ekf.model = self.model
        for rival in (self.twin_ekf, self.legs_ekf):
            if rival is not None:
                rival.model = self.model

    def _use_body(self, body: Body) -> None:
        """Set what the body decides: motion model, outline nodes, chains, ranges, postures."""
        self.body = body
        self.model = ConstantVelocity(body, self.settings.process_noise)
        self.nodes = model_nodes(body, ring_spacing=self.settings.ring_spacing)
        self.affects = chain_membership(body)
        self.anatomy = Anatomy(body)
        self.limit_index = self.anatomy.limit_index
        self.limit_low = self.anatomy.limit_low
        self.limit_high = self.anatomy.limit_high
        self.limb_postures = limb_postures(body)

    def apply_settings(self, settings: TrackerSettings) -> None:
        """Apply new noises, gates and limits from the next frame on, keeping the estimate."""
        self.settings = settings
        self.model = ConstantVelocity(self.body, settings.process_noise)
        self.ekf.model = self.model

    def set_pose(self, q: np.ndarray) -> None:
        """Use ``q`` (and zero velocity) at the next frame, like robot_localization's set_pose.

        A pose no person in the studio can take (:func:`anatomy.pose_problem`) raises ValueError
        with the reason and leaves the filter as it was.
        """
        from memo_ros.core.multiview.anatomy import pose_problem, studio_volume  # (here only)

        problem = pose_problem(self.body, q, studio_volume(list(self.cameras.values())))
        if problem:
            raise ValueError(problem)
        self.reset(pose=np.asarray(q, float))

    # ------------------------------------------------------------ frames
    def step(
        self,
        stamp_ns: int,
        contours: dict[str, np.ndarray],
        selected: dict[str, np.ndarray] | None = None,
        may_search: Callable[[], bool] | None = None,
        iterations: int | None = None,
    ) -> FrameResult:
        """Track one frame.

        Contour tables per camera; ``selected`` maps a camera to its (P,) part mask.
        ``may_search`` is asked before each search a tracked frame starts (a limb exchange try,
        the search again for lost limbs, a look at the twin; each costs several frames' work);
        False puts it off to a later frame (``searches_deferred``): a live node behind its cameras
        keeps its latency instead. None: every search runs when due. ``iterations``: this frame's
        relinearisations instead of the settings' (a live node behind its cameras takes fewer).
        """
        start = time.perf_counter()
        self._may_search = may_search or _always
        # a start weighs whole contours; a tracked frame takes samples_per_camera of them
        contours, rays = self._frame_rays(contours, thin=self.status == TRACKING)
        samples = sum(len(t) for t in contours.values())
        if not samples:
            return self._no_body(stamp_ns, start)
        masks = {
            c: (
                np.ones(len(PART_NAMES), bool)
                if selected is None or c not in selected
                else np.asarray(selected[c], bool)
            )
            for c in contours
        }
        initialised = from_pose = False
        dt = 0.0
        if self.status != TRACKING:
            from_pose = self.pending_pose is not None
            if from_pose:  # the heading a user or the studio gave counts as decided evidence
                self.evidence = self.settings.twin_evidence
            try:
                # a given pose that lost to its twin (_given_start) decides nothing: the two are
                # followed until the evidence separates them, as at a start from the silhouettes
                from_pose = self._initialise(stamp_ns, contours, rays) and from_pose
            finally:
                self._holding = True
            initialised = True
        else:
            if self.stamp_ns is None:  # never: a tracked frame sets it
                raise RuntimeError('tracking without a previous frame')
            dt = (stamp_ns - self.stamp_ns) * 1e-9
            last_pose = self.ekf.q.copy()
            self.ekf.predict(dt)
            if 0 < self.settings.reacquire_gap < dt:
                self._reacquire(last_pose, contours, rays, masks, samples, dt)
                iterations = max(iterations or 0, self.settings.recover_iterations)
        measure = self._measurement_function(contours, rays, masks)
        last: list[Measurements] = []  # the update's last linearisation (counts: _last_counts)

        def measure_and_keep(q: np.ndarray) -> Measurements:
            last[:] = [measure(q)]
            return last[0]

        report = self.ekf.update(
            measure_and_keep, iterations or self.settings.iterations, self.settings.gate_sigma
        )
        updated = self.ekf
        self.stamp_ns = stamp_ns
        matched, unselected = self._last_counts
        free = self.ekf.q.copy()  # before the ranges: its twin bends the right way
        if self.settings.hard_limits:
            self._clamp(self.ekf)
        # the misfit where the update last linearised: what the exchange and the search watch
        linearised = self._misfit(last[0], matched, samples) if last else None
        if self.settings.limb_exchange > 0 and not initialised:
            self._exchange_limbs(contours, rays, masks, samples, linearised)
        if self.settings.recover_margin > 0:  # unless an exchange replaced the pose
            self._recover(
                contours, rays, masks, samples, initialised,
                linearised if self.ekf is updated else None,
            )  # fmt: skip
        if self.settings.limb_recheck > 0 and not initialised:
            self._recheck_limbs(contours, rays, masks)
        self.path.add(stamp_ns * 1e-9, self.ekf.q)
        lead_cost = None  # the pose's robust misfit, once weighed against a rival
        if self.settings.twin_evidence > 0:
            lead_cost = self._follow_twin(
                contours, rays, masks, samples, dt, initialised and not from_pose, free
            )
        if self.settings.legs_evidence > 0:
            self._follow_legs(contours, rays, masks, samples, dt, initialised, lead_cost)
        consistent = (
            matched >= self.settings.min_matched_fraction * samples
            and not report.nis > self.settings.nis_limit
        )
        self.bad_frames = 0 if consistent else self.bad_frames + 1
        if self.bad_frames >= self.settings.lost_after:
            self.reset(use_initial_pose=False)
            self.status = LOST
            return FrameResult(
                stamp_ns,
                LOST,
                samples=samples,
                matched=matched,
                report=report,
                seconds=time.perf_counter() - start,
                reason=f'filter inconsistent for {self.settings.lost_after} frames '
                f'(NIS {report.nis:.1f}, {report.used}/{samples} samples used)',
            )
        self.status = TRACKING
        if not initialised:
            self._measure_proportions(contours)
        if self.settings.reacquire_gap > 0:  # only a frame after a gap compares with it
            self.centre = self._centre(contours)
        rotations, origins = self.body.forward_kinematics(self.ekf.q)
        return FrameResult(
            stamp_ns,
            TRACKING,
            self.ekf.q.copy(),
            coordinate_rates(self.ekf.q, self.ekf.v, self.model.groups),
            self.ekf.P.copy(),
            rotations,
            origins,
            samples,
            matched,
            unselected,
            report,
            initialised,
            time.perf_counter() - start,
            '' if consistent else 'inconsistent frame',
            self.heading_confidence,
            self.undecided,
            self.twin_swaps,
            self.legs_undecided,
            self.leg_swaps,
            self.limb_exchanges,
            self.recoveries,
            self.limbs_found,
            self.searches_deferred,
        )

    def _measure_proportions(self, contours: dict[str, np.ndarray]) -> None:
        """Measure a proportion in a due frame; once one is measured, track with its size."""
        if self.proportions is None:
            return
        body = self.proportions.frame(self.body, self.ekf.q, contours, self._search_allowed)
        if body is not None:
            self.change_body(body)

    def _centre(self, contours: dict[str, np.ndarray]) -> np.ndarray | None:
        """Return where the rays through each camera's contour centroid meet (None: < 2)."""
        return triangulate_centre([self.cameras[c] for c in contours], list(contours.values()))

    def _reacquire(
        self, last_pose: np.ndarray, contours, rays, masks, samples: int, dt: float
    ) -> None:
        """After a gap, start from the last pose moved with the silhouettes if it fits better.

        Over a gap of a quarter second or more the constant-velocity prediction (eq. 10) may be
        worth little: a velocity from before a slow start is zero while the person walked on,
        and one from a swinging leg carries it through its range. The other start is the last
        pose, its root moved on the floor as far as the centre of the silhouettes moved. The one
        that fits the frame's contours better is kept (a waving arm's prediction often wins).
        """
        centre = self._centre(contours)
        if centre is None or self.centre is None:
            return
        q = last_pose.copy()
        shift = centre[:2] - self.centre[:2]
        q[:2] += shift
        if self._fit_cost(q, contours, rays, masks, samples) < self._fit_cost(
            self.ekf.q, contours, rays, masks, samples
        ):
            v = np.zeros_like(self.ekf.v)
            v[:2] = shift / dt
            self.ekf.q, self.ekf.v = q, v
            self.reacquisitions += 1

    def _no_body(self, stamp_ns: int, start: float) -> FrameResult:
        """No contour from any camera: predict while the track is young, then lose it."""
        if self.status != TRACKING:
            return FrameResult(
                stamp_ns,
                self.status,
                seconds=time.perf_counter() - start,
                reason='no contours from any camera',
            )
        self.bad_frames += 1
        if self.bad_frames >= self.settings.lost_after:
            self.reset(use_initial_pose=False)
            self.status = LOST
            return FrameResult(
                stamp_ns,
                LOST,
                seconds=time.perf_counter() - start,
                reason=f'no camera saw the body for {self.settings.lost_after} frames',
            )
        if self.stamp_ns is None:  # never: a tracked frame sets it
            raise RuntimeError('tracking without a previous frame')
        self.ekf.predict((stamp_ns - self.stamp_ns) * 1e-9)
        self.stamp_ns = stamp_ns
        rotations, origins = self.body.forward_kinematics(self.ekf.q)
        return FrameResult(
            stamp_ns,
            TRACKING,
            self.ekf.q.copy(),
            coordinate_rates(self.ekf.q, self.ekf.v, self.model.groups),
            self.ekf.P.copy(),
            rotations,
            origins,
            seconds=time.perf_counter() - start,
            reason='no contours: predicted only',
        )

    def refit(self, q: np.ndarray, contours: dict[str, np.ndarray]) -> np.ndarray:
        """Return pose ``q`` fitted to one frame's contours from a broad prior, in the ranges.

        As a start refits its candidates (``init_iterations``, every part in every camera).
        """
        contours, rays, masks = self._whole_frame(contours)
        ekf = ArticulatedEKF(self.model)
        self._refit(ekf, np.asarray(q, float), contours, rays, masks)
        return ekf.q.copy()

    def local_fit(
        self, q: np.ndarray, contours: dict[str, np.ndarray], iterations: int
    ) -> np.ndarray:
        """Return pose ``q`` fitted to one frame from a narrow prior.

        A local fit (the start's ``init_sigma_*``, every part in every camera, in the ranges):
        where the pose is already about right, unlike :meth:`refit`'s search.
        """
        contours, rays, masks = self._whole_frame(contours)
        s = self.settings
        sigma = np.where(np.arange(len(q)) < 3, s.init_sigma_translation, s.init_sigma_rotation)
        P = np.diag(np.concatenate([sigma, sigma]) ** 2)
        return self._refined(q, np.zeros(len(q)), P, contours, rays, masks, iterations).q.copy()

    def misfit(self, q: np.ndarray, contours: dict[str, np.ndarray]) -> float:
        """Return pose ``q``'s robust misfit per contour sample (every part in every camera).

        As the start and the twin weigh poses (sigma^2 per sample); NaN without samples.
        """
        contours, rays, masks = self._whole_frame(contours)
        samples = sum(len(t) for t in contours.values())
        if not samples:
            return float('nan')
        return self._fit_cost(q, contours, rays, masks, samples) / samples

    def _whole_frame(self, contours: dict[str, np.ndarray]) -> tuple[dict, dict, dict]:
        """Return the frame's contours and rays (_frame_rays), and every part in every camera."""
        contours, rays = self._frame_rays(contours)
        return contours, rays, {c: np.ones(len(PART_NAMES), bool) for c in contours}

    def _frame_rays(
        self, contours: dict[str, np.ndarray], thin: bool = False
    ) -> tuple[dict, dict]:
        """Return the frame's non-empty contours of the rig's cameras, and their samples' rays.

        ``thin``: at most samples_per_camera of each camera's (thinned_samples).
        """
        s = self.settings
        budget = s.samples_per_camera if thin else 0
        contours = {
            c: thinned_samples(t, budget)
            for c, t in contours.items()
            if c in self.cameras and len(t)
        }
        rays = {
            c: contour_rays(self.cameras[c], t, s.contour_smoothing, s.smoothing_shift)
            for c, t in contours.items()
        }
        return contours, rays

    # ------------------------------------------------------------ the twin hypothesis
    @property
    def heading_confidence(self) -> float:
        """Return how sure the track is not its 180-degree, side-swapped twin.

        Logistic of the evidence.
        """
        if self.settings.twin_evidence <= 0:
            return 1.0
        k = np.log(99.0) / self.settings.twin_evidence  # 0.99 at the deciding evidence
        return float(1.0 / (1.0 + np.exp(-np.clip(k * self.evidence, -50.0, 50.0))))

    @property
    def undecided(self) -> bool:
        """Return whether both poses are followed and the evidence is not yet decisive."""
        return self.twin_ekf is not None and abs(self.evidence) < self.settings.twin_evidence

    @property
    def legs_undecided(self) -> bool:
        """Return whether the legs exchanged in place are followed beside the pose."""
        return self.legs_ekf is not None

    def _clamp(self, ekf: ArticulatedEKF) -> None:
        """Project a filter's pose into the anatomical ranges.

        The rates and covariance stay as they are: zeroing a rate at a bound without its
        correlations made a straight knee run away.
        """
        for arm in self.anatomy.reflexed_arms(ekf.q):  # exact: the arm does not move
            ekf.q, M = self.anatomy.unreflex(ekf.q, arm)
            ekf.v = M @ ekf.v
            ekf.P = _mapped_covariance(ekf.P, M)
        if self.anatomy.head_turned_back(ekf.q):  # exact too: the head does not move
            ekf.q, M = self.anatomy.turned_head(ekf.q)
            ekf.v = M @ ekf.v
            ekf.P = _mapped_covariance(ekf.P, M)
        ekf.q = self.anatomy.clamp(ekf.q)

    def _follow_twin(
        self, contours, rays, masks, samples: int, dt: float, start_twin: bool, free: np.ndarray
    ) -> float | None:
        """Track the leader's twin beside it; weigh the two by their fit to this frame's contours.

        The twin starts at every initialisation from the silhouettes, every
        ``twin_recheck`` frames and at an inconsistent frame, each time refitted to the frame
        from a broad prior as a start's candidates are.  The evidence is
        the difference of the two poses' robust contour costs per sample, plus
        ``travel_evidence`` times how clearly the leader walks forwards (travel.py),
        with memory; past ``twin_evidence`` the better pose is kept (the twin taking
        the leader's place if it is the better), or after ``twin_max_frames``.  A
        decided leader that walks backwards gets a look at its twin.  Returns the misfit of the
        pose that leads after this frame when the twin was weighed (None when it was not).
        """
        s = self.settings
        self.since_twin += 1
        velocity = self.path.velocity() if s.travel_evidence > 0 else None
        walking = travel_support(velocity, self.ekf.q, s.travel_speed)
        if self.twin_ekf is None:
            due = s.twin_recheck > 0 and self.since_twin >= s.twin_recheck
            self.look_wanted |= self.bad_frames == 1  # a run of bad frames: one look
            # a track walking backwards at walking pace: one look, again after TRAVEL_LOOK_FRAMES
            self.look_wanted |= (
                walking < -TRAVEL_LOOK_SUPPORT and self.since_twin >= TRAVEL_LOOK_FRAMES
            )
            if not (start_twin or due or self.look_wanted):
                return None
            if not start_twin and not self._search_allowed():
                return None  # due again next frame
            self.look_wanted = False
            self.twin_ekf = self._twin_filter(self.ekf, free)
            # a look again while decided is a check: the leader keeps its place unless the twin
            # wins within TWIN_CHECK_FRAMES; a start is a contest until the evidence decides
            self.twin_check = not start_twin and self.evidence > 0
            if start_twin and self._start_twin is not None:
                self.twin_ekf.q = self._start_twin
            self.twin_age = 0
            if start_twin:
                self.evidence = 0.0
            else:  # a look again: what was learnt counts, but no more than the deciding margin
                self.evidence = float(np.clip(self.evidence, -s.twin_evidence, s.twin_evidence))
        twin = self.twin_ekf
        counts = self._last_counts
        if self.twin_age:
            twin.predict(dt)
            twin.update(
                self._measurement_function(contours, rays, masks), s.iterations, s.gate_sigma
            )
        else:  # a fresh twin is refitted like a start: the mirror of a wrong pose fits badly
            # until it has settled, and one update let a turned track win every look again
            rates, spread = twin.v.copy(), twin.P.copy()  # the leader's, mapped
            every = {c: np.ones(len(PART_NAMES), bool) for c in contours}
            self._refit(twin, twin.q, contours, rays, every)
            if start_twin:
                twin.P = self.ekf.P.copy()
            else:
                twin.v, twin.P = rates, spread
        if s.hard_limits:
            self._clamp(twin)
        lead_cost = self._fit_cost(self.ekf.q, contours, rays, masks, samples)
        twin_cost = self._fit_cost(twin.q, contours, rays, masks, samples)
        self._last_counts = counts
        shape = 0.0
        if s.twin_silhouette > 0:
            people = person_silhouettes(self.cameras, contours)
            shape = s.twin_silhouette * (
                silhouette_disagreement(self.cameras, self.body, twin.q, people)
                - silhouette_disagreement(self.cameras, self.body, self.ekf.q, people)
            )
        self.evidence = (
            s.twin_memory * self.evidence
            + (twin_cost - lead_cost) / max(samples, 1)  # the fit to the contours
            + shape  # the fit to the silhouettes
            + s.travel_evidence * walking  # the direction of travel (the twin's is the opposite)
        )
        self.twin_age += 1
        if self.evidence < -s.twin_evidence or (
            self.twin_age >= s.twin_max_frames and self.evidence < 0
        ):
            self.ekf, self.twin_ekf = twin, self.ekf
            self.evidence = -self.evidence
            self.twin_swaps += 1
            lead_cost = twin_cost
            if self.legs_ekf is not None:  # the legs of the pose that lost: again, from the new
                self._start_legs()
        confirmed = self.twin_check and self.twin_age >= TWIN_CHECK_FRAMES and self.evidence > 0
        if confirmed or self.evidence > s.twin_evidence or self.twin_age >= s.twin_max_frames:
            self.twin_ekf = None
            self.since_twin = 0
        return lead_cost

    # ------------------------------------------------------------ which leg is which
    def _start_legs(self) -> None:
        """Start following the pose with its legs exchanged in place (the rates follow places)."""
        _, M = self.anatomy.exchange(self.ekf.q, 'legs')
        self.legs_ekf = ArticulatedEKF(self.model)
        self.legs_ekf.q = legs_in_place(self.body, self.ekf.q)
        self.legs_ekf.v = M @ self.ekf.v
        self.legs_ekf.P = _mapped_covariance(self.ekf.P, M)
        self.legs_age, self.leg_evidence = 0, 0.0

    def _follow_legs(
        self,
        contours,
        rays,
        masks,
        samples: int,
        dt: float,
        start: bool,
        lead_cost: float | None = None,
    ) -> None:
        """Track the pose with its legs exchanged in place beside it; keep the better labelling.

        The rival starts at every start, and again from the new leader when the twin takes the
        leader's place (_follow_twin).  It is weighed as the twin is (the robust contour cost per
        sample, with ``twin_memory``): past ``legs_evidence`` the better labelling is kept, the
        rival taking the leader's place if it is the better (a twin being followed then starts
        again from the new leader).  It is dropped once both put each leg in the same place, after
        ``twin_max_frames`` with the better of the two kept, or when it is behind after
        TWIN_CHECK_FRAMES, as a twin's check is: a rival that loses its first frames and then wins
        is mostly a leader that lost a leg for a while (without this, 3 of 10 first passes of the
        Pose2Sim demo, started at heights 1e-6 apart, swapped the legs so for 15 - 37 frames).
        ``lead_cost``: the pose's misfit if this frame already weighed it (_follow_twin's).
        """
        s = self.settings
        if start:
            self._start_legs()
        rival = self.legs_ekf
        if rival is None:
            return
        counts = self._last_counts
        if self.legs_age:
            rival.predict(dt)
            rival.update(
                self._measurement_function(contours, rays, masks), s.iterations, s.gate_sigma
            )
            if s.hard_limits:
                self._clamp(rival)
        if lead_cost is None:
            lead_cost = self._fit_cost(self.ekf.q, contours, rays, masks, samples)
        rival_cost = self._fit_cost(rival.q, contours, rays, masks, samples)
        self._last_counts = counts
        self.leg_evidence = s.twin_memory * self.leg_evidence + (rival_cost - lead_cost) / max(
            samples, 1
        )
        self.legs_age += 1
        if self.leg_evidence < -s.legs_evidence or (
            self.legs_age >= s.twin_max_frames and self.leg_evidence < 0
        ):
            self.ekf, rival = rival, self.ekf
            self.legs_ekf = rival
            self.leg_evidence = -self.leg_evidence
            self.leg_swaps += 1
            self.exchange_tried['legs'] = self.anatomy.difference(self.ekf.q, 'legs')
            if self.twin_ekf is not None:  # the twin of the labelling that lost: again, refitted
                self.twin_ekf = self._twin_filter(self.ekf, self.ekf.q)
                self.twin_age = 0
        if (
            self.leg_evidence > s.legs_evidence
            or (self.legs_age >= TWIN_CHECK_FRAMES and self.leg_evidence > 0)
            or self.legs_age >= s.twin_max_frames
            or legs_alike(self.body, self.ekf.q, rival.q)
        ):
            self.legs_ekf = None

    def _exchange_limbs(
        self, contours, rays, masks, samples: int, linearised: float | None = None
    ) -> None:
        """Exchange a pair of limbs when the exchanged pair fits this frame's contours better.

        A fast kick seen from the side moves the model's leg nearer that camera whichever leg
        kicks, and the other views tell the two apart only once the legs are exchanged.  A pair is
        tried whenever its left-right difference has changed by ``limb_exchange`` since its last
        try (fast limb motion): exchanged, refined by one iteration and kept if it fits better by
        ``exchange_margin`` per sample than the pose as it stands given the same iteration (an
        extra iteration alone lowers the misfit of a pose the frame's two have not settled).  A
        try that does not beat by that margin ``linearised``, the update's own misfit at its last
        linearisation, is dropped before the pose as it stands is refined: most tries fail, and
        this spares each failed one an iteration and a misfit.
        """
        s = self.settings
        counts = self._last_counts
        margin = s.exchange_margin * samples
        current = None
        for pair in self.anatomy.limbs:
            difference = self.anatomy.difference(self.ekf.q, pair)
            if np.max(np.abs(difference - self.exchange_tried[pair])) < s.limb_exchange:
                continue
            if not self._search_allowed():
                break  # the pair stays due
            self.exchange_tried[pair] = difference
            q, M = self.anatomy.exchange(self.ekf.q, pair)
            trial = self._refined(
                q, M @ self.ekf.v, _mapped_covariance(self.ekf.P, M), contours, rays, masks
            )
            cost = self._fit_cost(trial.q, contours, rays, masks, samples)
            if current is None and linearised is not None and cost >= linearised - margin:
                continue  # no better than the pose's misfit before the update's last iteration
            if current is None:  # the pose as it stands, given the same extra iteration
                current = self._fit_cost(
                    self._refined(self.ekf.q, self.ekf.v, self.ekf.P, contours, rays, masks).q,
                    contours,
                    rays,
                    masks,
                    samples,
                )
            if cost < current - margin:
                self.ekf = trial
                self.limb_exchanges += 1
                self.exchange_tried[pair] = self.anatomy.difference(trial.q, pair)
                current = cost
        self._last_counts = counts

    def _recover(
        self,
        contours,
        rays,
        masks,
        samples: int,
        initialised: bool,
        linearised: float | None = None,
    ) -> None:
        """Search again from a broad prior when the fit is much worse than the track's usual.

        A limb the filter lost (the fast kick followed by the other leg, an arm dragged up by its
        raised neighbour) leaves the pose in a local minimum whose misfit is well above the
        track's running usual, and the filter's own small steps cannot leave it.  Then the pose,
        and the pose with each pair of limbs exchanged, are refitted from a broad prior like a
        start (``recover_iterations``, within the ranges), in that order until one is back within
        the margin of the usual, and the best is kept if it fits better: re-initialising what was
        lost without forgetting the rest (the rates and covariance stay). The misfit watched is
        ``linearised``, the update's own at its last linearisation (no extra evaluation in a usual
        frame) when given; a search compares the pose's exact misfit.
        """
        s = self.settings
        counts = self._last_counts
        exact = linearised is None
        if linearised is None:
            linearised = self._fit_cost(self.ekf.q, contours, rays, masks, samples)
        cost = linearised / max(samples, 1)
        if initialised or self.usual_cost is None:
            self.usual_cost = cost
            self._last_counts = counts
            return
        if cost > self.usual_cost + s.recover_margin:
            if not self._search_allowed():  # the usual is not raised by a frame left unsearched
                self._last_counts = counts
                return
            if not exact:
                cost = self._fit_cost(self.ekf.q, contours, rays, masks, samples)
                cost /= max(samples, 1)
            best: tuple[float, ArticulatedEKF, np.ndarray] | None = None
            starts = [(self.ekf.q, np.eye(self.body.n_coordinates))]
            starts += [self.anatomy.exchange(self.ekf.q, pair) for pair in self.anatomy.limbs]
            for q, M in starts:
                trial, trial_cost = self._recover_start(q, contours, rays, masks, samples)
                if trial_cost < cost and (best is None or trial_cost < best[0]):
                    best = (trial_cost, trial, M)
                if best is not None and best[0] < self.usual_cost + s.recover_margin:
                    break  # back to the usual misfit: the other starts are not tried
            if s.pair_search > 0 and (
                best is None or best[0] >= self.usual_cost + s.recover_margin
            ):
                beaten = cost if best is None else min(cost, best[0])
                found = self._search_pairs(contours, rays, masks, samples)
                # one within the margin of the best is refitted as the other starts (the rest of
                # the body moves too: a squat's pelvis) and kept if it then fits clearly better
                if found is not None and found[0] < beaten + s.recover_margin:
                    trial, trial_cost = self._recover_start(
                        found[1], contours, rays, masks, samples
                    )
                    if trial_cost < beaten - s.pair_search:
                        best = (trial_cost, trial, np.eye(self.body.n_coordinates))
            if best is not None:
                cost, trial, M = best
                self.ekf.q = trial.q
                self.ekf.v = M @ self.ekf.v
                self.ekf.P = _mapped_covariance(self.ekf.P, M)
                self.recoveries += 1
        self.usual_cost = s.recover_memory * self.usual_cost + (1 - s.recover_memory) * cost
        self._last_counts = counts

    def _recover_start(
        self, q: np.ndarray, contours, rays, masks, samples: int
    ) -> tuple[ArticulatedEKF, float]:
        """Return a filter refitted from ``q`` under a broad prior, and its misfit per sample."""
        trial = ArticulatedEKF(self.model)
        self._refit(trial, q, contours, rays, masks, iterations=self.settings.recover_iterations)
        cost = self._fit_cost(trial.q, contours, rays, masks, samples) / max(samples, 1)
        return trial, cost

    def _search_pairs(
        self, contours, rays, masks, samples: int
    ) -> tuple[float, np.ndarray] | None:
        """Return the best pose with a pair of limbs found again together, and its misfit/sample.

        A fast kick the filter followed with the standing leg leaves both legs wrong, and neither
        the pair exchanged (both still bent wrong) nor one leg searched with the other where it is
        (the wrong leg covers the kick's outline) finds the way out.  Each pair's limbs are posed
        together in the best few canonical postures of each (limb_search.pair_postures), the
        pair's best combinations on the cheap score are refined by the update, and the one that
        fits best on the robust misfit is returned (None: no pair could be posed).
        """
        score = self._posture_scorer(contours, rays)
        q = self.ekf.q
        limbs = {p.limb: p for p in self.limb_postures}
        scores = {name: score(np.vstack([q, p.apply(q)]), p.parts) for name, p in limbs.items()}
        best: tuple[float, np.ndarray] | None = None
        for kind in ('leg', 'arm'):
            a, b = limbs[f'{kind}_l'], limbs[f'{kind}_r']
            poses = pair_postures(a, b, q, scores[a.limb], scores[b.limb])
            parts = np.concatenate([a.parts, b.parts])
            cheap = score(poses, parts)
            index = np.concatenate([a.index, b.index])
            for start in poses[np.argsort(cheap)[:PAIR_REFINE_STARTS]]:
                trial = self._refined_limb(start, index, contours, rays, masks)
                cost = self._fit_cost(trial, contours, rays, masks, samples) / max(samples, 1)
                if best is None or cost < best[0]:
                    best = (cost, trial)
        return best

    def _recheck_limbs(self, contours, rays, masks) -> None:
        """Search each limb again every ``limb_recheck`` frames; keep one found to fit better.

        The limbs fall due on consecutive frames, one a frame (every limb's cheap score in one
        frame made it 67 - 89 ms against 18 - 20 on 3 cameras, more than a 30 Hz frame period).
        """
        self.since_limbs += 1
        due = self.since_limbs >= self.settings.limb_recheck
        if not due.any() or not self._search_allowed():
            return
        self.since_limbs[due] = 0
        counts = self._last_counts
        limbs = [p for p, d in zip(self.limb_postures, due) if d]
        q, moved = self._search_limbs(
            self.ekf.q, contours, rays, masks, tracking=True, limbs=limbs
        )
        if moved:
            self.ekf.q = q
            self.limbs_found += moved
        self._last_counts = counts

    def _search_allowed(self) -> bool:
        """Return whether a due search may run in this frame; count it deferred if not."""
        if self._may_search():
            return True
        self.searches_deferred += 1
        return False

    def _refined(self, q, v, P, contours, rays, masks, iterations: int = 1) -> ArticulatedEKF:
        """Return a filter at (q, v, P) after ``iterations`` more updates, in the ranges."""
        ekf = ArticulatedEKF(self.model)
        ekf.q, ekf.v, ekf.P = np.array(q, float), np.array(v, float), np.array(P, float)
        ekf.update(
            self._measurement_function(contours, rays, masks), iterations, self.settings.gate_sigma
        )
        if self.settings.hard_limits:
            self._clamp(ekf)
        return ekf

    def _twin_filter(self, ekf: ArticulatedEKF, free: np.ndarray) -> ArticulatedEKF:
        """Return a filter at the twin of ``ekf``'s state, its covariance carried by the same map.

        The twin is taken of ``free``, the pose before the ranges were imposed: a hinge the leader
        had to straighten bends the right way in it.
        """
        twin = ArticulatedEKF(self.model)
        M = self.anatomy.tangent_map()
        twin.q = self.anatomy.twin(free)
        twin.v = M @ ekf.v
        twin.P = _mapped_covariance(ekf.P, M)
        return twin

    def _refit(
        self,
        ekf: ArticulatedEKF,
        q: np.ndarray,
        contours,
        rays,
        masks,
        clamp: bool = True,
        iterations: int | None = None,
    ) -> UpdateReport:
        """Fit a start pose to one frame from a broad prior.

        ``init_iterations`` relinearisations in rounds of five, each round ending in the anatomical
        ranges (hard limits) and starting anew.
        """
        s = self.settings
        sigma_q = np.where(np.arange(len(q)) < 3, 0.3, 0.5)
        sigma_v = np.where(np.arange(len(q)) < 3, 0.3, 0.5)
        report = UpdateReport()
        left = max(s.init_iterations if iterations is None else iterations, 1)
        while left > 0:
            ekf.initialize(q, None, sigma_q, sigma_v)
            report = ekf.update(  # a search from a broad prior: every force pulls in full
                self._measurement_function(contours, rays, masks, robust=False),
                min(left, 5),
                gate=1e6,
            )
            left -= 5
            if s.hard_limits and clamp:
                self._clamp(ekf)
            q = ekf.q
        return report

    def _fit_cost(self, q: np.ndarray, contours, rays, masks, samples: int) -> float:
        """Robust misfit of pose ``q`` to the contours.

        Sum of min(z^2, gate^2) over the samples, where z is a matched sample's normalised force
        and an unmatched sample counts the full gate^2.
        """
        m = self._measurement_function(contours, rays, masks)(q)
        return self._misfit(m, self._last_counts[0], samples)

    def _misfit(self, m: Measurements, matched: int, samples: int) -> float:
        """Robust misfit of measurements ``m``, ``matched`` of ``samples`` contour samples."""
        gate2 = self.settings.gate_sigma**2
        z2 = (m.r / m.sigma) ** 2 if len(m) else np.zeros(0)
        return float(np.minimum(z2, gate2).sum() + max(samples - matched, 0) * gate2)

    # ------------------------------------------------------------ measurement model
    def _candidates(
        self,
        cams: list[Camera],
        rays: dict,
        rotations: np.ndarray,
        origins: np.ndarray,
        frame: dict,
    ) -> list[Candidates]:
        """Per camera, the nodes that may be on an outline near its samples.

        Which nodes, and which are on the predicted outline (:class:`FirstOutline`, kept in
        ``frame``), is decided once per frame (at the first linearisation, like a per-frame
        visibility test) and kept through the iterations.
        """
        if not frame:
            out = []
            every = rig_outline_candidates(cams, self.nodes, rotations, origins)
            if self._holds():  # every outline node, for the silhouette's hold (_hold_rows)
                frame['hold'] = [c.subset(np.all(np.isfinite(c.uv), axis=1)) for c in every]
            for cam, cand in zip(cams, every):
                near = np.all(np.isfinite(cand.uv), axis=1)
                if len(
                    rays[cam.name].uv
                ):  # nodes no sample can reach (twice the search radius) are never matched
                    near[near] = rays[cam.name].within(cand.uv[near], 2 * self.settings.search_px)
                out.append(cand.subset(near))
            frame['outline'] = FirstOutline(
                cams, out, rotations, origins, self.body, self.settings.outline_probe_px
            )
            return out
        if 'hold_keys' in frame:  # the hold's nodes hold these: one projection for both
            every = rig_outline_candidates(
                cams, self.nodes, rotations, origins, frame['hold_keys']
            )
            frame['hold_now'] = every
            return [
                cand.subset(np.isin(_node_keys(cand), keys) & np.all(np.isfinite(cand.uv), axis=1))
                for cand, keys in zip(every, frame['outline'].keys)
            ]
        cands = rig_outline_candidates(cams, self.nodes, rotations, origins, frame['outline'].keys)
        return [cand.subset(np.all(np.isfinite(cand.uv), axis=1)) for cand in cands]

    def _hip_twist_rows(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Each hip's twist as a pseudo-measurement of 0 (``hip_twist_sigma``), or None if off.

        It ties the pelvis's heading to the legs: silhouettes of an elliptic torso show its heading
        only weakly, and the hips' ball joints let it turn while both thighs turn back.
        """
        sigma = self.settings.hip_twist_sigma
        if sigma <= 0:
            return None
        twists = self.anatomy.hip_twists
        return _coordinate_rows(self.body.n_coordinates, twists, -q[twists], sigma)

    def _limit_rows(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Joint limits as pseudo-measurements (soft inequality constraints).

        Active where q leaves its range.
        """
        if self.settings.limit_sigma <= 0:
            return None
        v = q[self.limit_index]
        target = np.clip(v, self.limit_low, self.limit_high)
        active = target != v
        if not active.any():
            return None
        return _coordinate_rows(
            self.body.n_coordinates,
            self.limit_index[active],
            target[active] - v[active],
            self.settings.limit_sigma,
        )

    def _measurement_function(self, contours, rays, masks, robust: bool = True):
        """measure(q) -> Measurements.

        The forces of eq. 14-15 linearised at q (Jacobians of eq. 9, 16); with ``robust`` (and a
        positive ``robust_scale``) the image forces carry their Cauchy scales for the update.
        """
        s = self.settings
        n = self.body.n_coordinates
        self._last_counts = (0, 0)
        frame: dict = {}  # the first linearisation's outline test and hold nodes (_candidates)
        robust_scale = s.robust_scale if robust and s.robust_scale > 0 else np.inf
        fields = self._silhouettes(contours) if self._holds() else {}
        # noise per unit of contour length: denser samples each carry less independent information
        density = {
            c: np.sqrt(REFERENCE_SPACING_PX / sample_spacing(t)) for c, t in contours.items()
        }

        def measure(q: np.ndarray) -> Measurements:
            rotations, origins = self.body.forward_kinematics(q)
            chain = chain_axes(self.body, q, rotations, origins, self.affects)
            parts, points, g, rows_r, rows_s, normal_rows = [], [], [], [], [], []
            rows_robust: list[np.ndarray] = []  # Cauchy scales of the rows so far (inf: none)
            matched = unselected = 0
            cams = [self.cameras[c] for c in contours]
            cands = self._candidates(cams, rays, rotations, origins, frame)
            outline = frame['outline']
            first = [outline.index(k, cand) for k, cand in enumerate(cands)]
            if s.symmetric:  # every usable node pulls: all of them are needed
                for cand, usable in zip(cands, outline.usable(first)):
                    cand.usable = usable
            forces = [
                assign_forces(rays[cam.name], cand, self.nodes.epsilon, s.search_px, s.symmetric)
                for cam, cand in zip(cams, cands)
            ]
            if (
                not s.symmetric
            ):  # a sample whose nearest node is not on the predicted outline is dropped
                on_outline = outline.usable([f[m.node] for f, m in zip(first, forces)])
                forces = [
                    Matches(m.sample[on], m.node[on], m.distance[on])
                    for m, on in zip(forces, on_outline)
                ]
            for cam, cand, m in zip(cams, cands, forces):
                cam_name = cam.name
                cam_rays = rays[cam_name]
                use = masks[cam_name][cand.part[m.node]]
                unselected += int(len(use) - np.count_nonzero(use))
                sample, node = m.sample[use], m.node[use]
                tied = np.zeros(len(cam_rays.uv), bool)
                tied[sample] = True
                matched += int(np.count_nonzero(tied))
                if not len(sample):
                    continue
                parts.append(cand.part[node])
                points.append(cand.points[node])
                tied_nodes = np.zeros(
                    len(cand), bool
                )  # eq. 9: H at each node tied to a sample, camera frame
                tied_nodes[node] = True
                J_cam = cam.projection_jacobian_camera(
                    cam.world_to_camera(cand.points[tied_nodes])
                )
                m_out = cam_rays.outward[sample]
                J_cam = J_cam[(np.cumsum(tied_nodes) - 1)[node]]
                g.append(
                    (m_out[:, 0, None] * J_cam[:, 0] + m_out[:, 1, None] * J_cam[:, 1])
                    @ cam.R_world_cam.T
                )  # eq. 9: m^T H R^-1
                offset = cam_rays.uv[sample] - cand.uv[node]
                rows_r.append(m_out[:, 0] * offset[:, 0] + m_out[:, 1] * offset[:, 1])  # eq. 14
                side = ~cand.rim[node]
                # the smoothing correction is itself uncertain: its size joins the noise
                sigma = np.where(side, s.sigma_px, s.sigma_rim_px) * density[cam_name]
                rows_s.append(np.hypot(sigma, cam_rays.bias[sample]))
                rows_robust.append(robust_scale * rows_s[-1])
                if s.sigma_normal > 0 and side.any():
                    normals = cand.normal[node][side]
                    Jn = normal_jacobian(
                        chain, parts[-1][side], normals, rotations[parts[-1][side]][:, :, 2]
                    )
                    normal_rows.append(
                        (
                            Jn.reshape(-1, n),
                            (cam_rays.k[sample][side] - normals).reshape(-1),  # eq. 15
                            np.full(3 * int(side.sum()), s.sigma_normal),
                        )
                    )
            if fields:
                hold = self._hold_rows(cams, fields, frame, rotations, origins)
                if hold is not None:
                    parts.append(hold[0])
                    points.append(hold[1])
                    g.append(hold[2])
                    rows_r.append(hold[3])
                    rows_s.append(np.full(len(hold[3]), s.hold_sigma_px))
                    rows_robust.append(np.full(len(hold[3]), np.inf))
            # eq. 9: m^T H R^-1 L, every camera's image forces at once
            rows_H = (
                [
                    projected_rows(
                        chain, np.concatenate(parts), np.concatenate(points), np.concatenate(g)
                    )
                ]
                if parts
                else []
            )
            for H, r, sigma in normal_rows:
                rows_H.append(H)
                rows_r.append(r)
                rows_s.append(sigma)
            self._last_counts = (matched, unselected)
            for pseudo in (self._hip_twist_rows(q), self._limit_rows(q)):
                if pseudo is not None:
                    rows_H.append(pseudo[0])
                    rows_r.append(pseudo[1])
                    rows_s.append(pseudo[2])
            if not rows_r:
                return Measurements.empty(n)
            r = np.concatenate(rows_r)
            scales = None
            if robust_scale < np.inf:  # normal and limit rows (after the forces) are not robust
                scales = np.full(len(r), np.inf)
                if rows_robust:
                    force_scales = np.concatenate(rows_robust)
                    scales[: len(force_scales)] = force_scales
            return Measurements(np.concatenate(rows_H), r, np.concatenate(rows_s), scales)

        return measure

    def _holds(self) -> bool:
        """Return whether the silhouette holds the body now (on, and not in a heading search)."""
        return self.settings.hold_sigma_px > 0 and self._holding

    def _silhouettes(self, contours: dict[str, np.ndarray]) -> dict:
        """Return the frame's silhouette fields, computed once for all its linearisations."""
        if self._fields_of is not contours:
            self._fields_of = contours
            self._fields = silhouette_fields(self.cameras, contours, self.settings.hold_hull)
        return self._fields

    def _hold_rows(self, cams, fields, frame, rotations, origins):
        """Return the silhouette's hold (silhouette_hold.py) on the outline nodes outside it.

        Returns (parts, points, g, residuals) like the image forces' rows, or None.  The nodes are
        the first linearisation's outline nodes of every part, re-projected at each iterate.
        """
        s = self.settings
        if 'hold_keys' not in frame:
            cands = frame['hold']
            frame['hold_keys'] = [_node_keys(c) for c in cands]
        elif 'hold_now' in frame:  # projected at this iterate by _candidates
            cands = frame.pop('hold_now')
        else:
            cands = rig_outline_candidates(
                cams, self.nodes, rotations, origins, frame['hold_keys']
            )
        parts, points, g, r = [], [], [], []
        for cam, cand in zip(cams, cands):
            field = fields.get(cam.name)
            if field is None or not len(cand):
                continue
            out, direction, residual = outside_pull(
                field, cand.uv, s.hold_tolerance_px, s.hold_cap_px
            )
            if not len(out):
                continue
            J = cam.projection_jacobian_camera(cam.world_to_camera(cand.points[out]))
            ok = np.all(np.isfinite(J.reshape(len(out), -1)), axis=1)
            out, direction, residual, J = out[ok], direction[ok], residual[ok], J[ok]
            parts.append(cand.part[out])
            points.append(cand.points[out])
            g.append(
                (direction[:, 0, None] * J[:, 0] + direction[:, 1, None] * J[:, 1])
                @ cam.R_world_cam.T
            )
            r.append(residual)
        if not parts:
            return None
        return np.concatenate(parts), np.concatenate(points), np.concatenate(g), np.concatenate(r)

    # ------------------------------------------------------------ initialisation
    def _initialise(self, stamp_ns: int, contours, rays) -> bool:
        """Start from the given pose or from the silhouettes; return whether the heading stands.

        Root from the rays through their centres, a standing posture at the best of several
        headings, refined by the update itself.  The silhouette's hold is off while the headings
        are searched (it pulled a fit turned the wrong way round into place) and on for the most
        promising, each with its limbs searched first: a start while an arm is raised (a tracker
        restarted mid-motion) otherwise turned the torso and twisted the neck to reach the arm.
        """
        s = self.settings
        sigma_q = np.full(self.body.n_coordinates, s.init_sigma_rotation)
        sigma_q[:3] = s.init_sigma_translation
        sigma_v = np.full(self.body.n_coordinates, 0.5)
        sigma_v[:3] = 0.3
        masks = {c: np.ones(len(PART_NAMES), bool) for c in contours}
        self._holding = False
        if self.pending_pose is not None:
            start, decided = self._given_start(contours, rays, masks)
            self.ekf.initialize(start, None, sigma_q, sigma_v)
            return decided
        centre = triangulate_centre(
            [self.cameras[c] for c in contours], [contours[c] for c in contours]
        )
        neutral = self.body.neutral()
        samples = sum(len(t) for t in contours.values())
        candidates: list[tuple[float, np.ndarray, np.ndarray]] = []
        for k in range(max(s.init_headings, 1)):
            q = neutral.copy()
            heading = 2 * np.pi * k / max(s.init_headings, 1)
            q[3:6] = matrix_to_rotvec(rot_z(heading))
            if centre is not None:
                q[0:2] = centre[0:2]
            self._refit(self.ekf, q, contours, rays, masks, clamp=False)
            free = self.ekf.q.copy()
            # the free fit and its twin, both within the ranges: a fit turned backwards whose knees
            # had to overextend is, as its twin, a fit the right way round
            pair = (self._in_ranges(free), self._in_ranges(self.anatomy.twin(free)))
            for own, other in (pair, pair[::-1]):
                cost = self._fit_cost(own, contours, rays, masks, samples)
                candidates.append((cost, own, other))
        # the most promising, their limbs searched, are refitted within the ranges and held by the
        # silhouette before one is chosen
        self._holding = True
        best: tuple[float, np.ndarray, np.ndarray, int] | None = None
        people = person_silhouettes(self.cameras, contours) if s.twin_silhouette > 0 else {}
        for _, own, other in sorted(candidates, key=lambda c: c[0])[: max(s.init_refits, 1)]:
            moved = 0
            if s.limb_search > 0:
                own, moved = self._search_limbs(own, contours, rays, masks)
            self._refit(self.ekf, own, contours, rays, masks)
            cost = self._fit_cost(self.ekf.q, contours, rays, masks, samples) / max(samples, 1)
            if people:  # the silhouettes weigh as in the twin contest
                cost += s.twin_silhouette * silhouette_disagreement(
                    self.cameras, self.body, self.ekf.q, people
                )
            if best is None or cost < best[0]:
                best = (cost, self.ekf.q.copy(), other, moved)
        assert best is not None
        _, start, self._start_twin, moved = best
        if s.limb_search > 0:  # the refit may have left a limb's posture behind
            start, more = self._search_limbs(start, contours, rays, masks)
            moved += more
        if moved:
            self._start_twin = self._in_ranges(self.anatomy.twin(start))
            self.limbs_found += moved
        self.ekf.initialize(start, None, sigma_q, sigma_v)
        return False

    def _in_ranges(self, q: np.ndarray) -> np.ndarray:
        """Return ``q`` projected into the anatomical ranges (as it is without hard_limits)."""
        return self.anatomy.project(q) if self.settings.hard_limits else np.asarray(q)

    def _search_limbs(
        self,
        q: np.ndarray,
        contours,
        rays,
        masks,
        tracking: bool = False,
        limbs: list[LimbPostures] | None = None,
    ) -> tuple[np.ndarray, int]:
        """Return ``q`` with each limb moved to the posture that fits the frame (limb_search.py).

        And how many limbs moved; ``limbs``: only these (default: every limb).

        Round by round, the limb whose best canonical posture gains most on the cheap score is
        refined from its best two postures by the update (``_refined_limb``) and the result kept
        if its robust misfit is ``limb_search`` per sample below the pose's; a kept limb is not
        tried again.  ``tracking``: kept if instead its outline fits the contours better on the
        cheap score by ``limb_recheck_gain`` per sample.  The robust misfit, whose 1 px noise a
        limb refined in a few iterations does not meet as well as one the filter settled over
        many frames, preferred the arm the Pose2Sim dancer had swung up left folded against his
        head to the arm refined along the arm's outline.
        """
        s = self.settings
        samples = sum(len(t) for t in contours.values())
        score = self._posture_scorer(contours, rays)
        # (while tracking, each limb's outline is weighed on the cheap score instead)
        cost = 0.0 if tracking else self._fit_cost(q, contours, rays, masks, samples)
        # the least gain a start must show on the cheap score to be refined
        least = LIMB_RECHECK_START_GAIN * s.limb_recheck_gain * samples if tracking else 0.0
        searched = list(self.limb_postures if limbs is None else limbs)
        left = list(searched)
        while left:
            gains = []
            for postures in left:
                poses = np.vstack([q, postures.apply(q)])
                scores = score(poses, postures.parts)
                order = np.argsort(scores[1:])[:LIMB_REFINE_STARTS] + 1
                gains.append((scores[0] - scores[order[0]], postures, poses[order]))
            kept = None
            for gain, postures, starts in sorted(gains, key=lambda g: -g[0]):
                if gain <= least:
                    break
                for start in starts:
                    trial = self._refined_limb(start, postures.index, contours, rays, masks)
                    if tracking:
                        compared = score(np.vstack([q, trial]), postures.parts)
                        trial_cost = float(compared[1])
                        better = compared[0] - compared[1] > s.limb_recheck_gain * samples
                    else:
                        trial_cost = self._fit_cost(trial, contours, rays, masks, samples)
                        better = trial_cost < cost - s.limb_search * samples
                    if better and (kept is None or trial_cost < kept[0]):
                        kept = (trial_cost, trial, postures)
                if kept is not None:
                    break
            if kept is None:
                break
            cost, q, done = kept
            left.remove(done)
        return q, len(searched) - len(left)

    def _posture_scorer(self, contours, rays) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """Return the frame's cheap score of poses (K, n) differing in ``parts`` (posture_scores).

        Against every camera's contour samples and the silhouette fields of the hold (made
        whether or not it holds).
        """
        names = list(contours)
        cams = [self.cameras[c] for c in names]
        uv = [rays[c].uv for c in names]
        fields = self._silhouettes(contours)
        field_list = [fields.get(c) for c in names]
        return lambda poses, parts: posture_scores(
            self.body, self.nodes, cams, uv, field_list, poses, parts
        )

    def _given_start(self, contours, rays, masks) -> tuple[np.ndarray, bool]:
        """Return the start from the given pose, its limbs found, and whether its heading stands.

        Limbs found for a pose given the wrong way round fit its silhouettes as well as the
        ranges let them, and its twin, with the mirrored limbs bent the wrong way and clamped,
        would then lose every later comparison: so when the search moved a limb, the twin of the
        given pose gets the same search, and starts if it fits better by ``twin_evidence`` per
        sample.  The given heading then no longer stands: the pose with it is followed as the
        twin until the evidence separates the two, as at a start from the silhouettes.
        """
        s = self.settings
        given = self.pending_pose
        assert given is not None
        start, moved = given, 0
        if s.limb_search > 0:  # the given pose's limbs need not be where the person's are
            start, moved = self._search_limbs(given, contours, rays, masks)
        decided = True
        if moved and s.twin_evidence > 0:
            twin, twin_moved = self._search_limbs(
                self._in_ranges(self.anatomy.twin(given)), contours, rays, masks
            )
            samples = sum(len(t) for t in contours.values())
            own = self._fit_cost(start, contours, rays, masks, samples)
            other = self._fit_cost(twin, contours, rays, masks, samples)
            if other < own - s.twin_evidence * samples:
                self.twin_swaps += 1
                self._start_twin, start, moved, decided = start, twin, twin_moved, False
        self.limbs_found += moved
        return start, decided

    def _refined_limb(self, q: np.ndarray, limb: np.ndarray, contours, rays, masks) -> np.ndarray:
        """Return ``q`` after LIMB_REFINE_ITERATIONS updates, in the ranges.

        From a broad prior on the ``limb``'s coordinates and a narrow one on the rest of the body
        (LIMB_HOLD_SIGMA): the rest, refined from the broad prior too, moved to make room for a
        wrong limb (studio-dance with the tracker's body measured: 12 of 16 runs passed, 14 with
        the rest held).
        """
        start = ArticulatedEKF(self.model)
        sigma_q = np.full(len(q), LIMB_HOLD_SIGMA)
        sigma_q[limb] = LIMB_REFINE_SIGMA
        start.initialize(q, None, sigma_q, np.full(len(q), 0.5))
        refined = self._refined(
            start.q, start.v, start.P, contours, rays, masks, LIMB_REFINE_ITERATIONS
        )
        return refined.q


def _coordinate_rows(
    n: int, index: np.ndarray, residual: np.ndarray, sigma: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pseudo-measurements of single coordinates: unit rows (len(index), n), residuals, noise."""
    H = np.zeros((len(index), n))
    H[np.arange(len(index)), index] = 1.0
    return H, residual, np.full(len(index), sigma)


def _mapped_covariance(P: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Return the (q, v) covariance ``P`` carried by the tangent map ``M`` applied to both."""
    T = np.kron(np.eye(2), M)
    return T @ P @ T.T


def _node_keys(cand: Candidates) -> np.ndarray:
    """Return the node keys of outline candidates (rig_outline_candidates gives them)."""
    if cand.key is None:
        raise ValueError('outline candidates without node keys')
    return cand.key


class FirstOutline:
    """The cameras' candidate nodes at a frame's first linearisation and which are on the outline.

    Which of them are on the predicted outline there (:func:`rig_on_outline`).  The test is made
    on demand, once per node and frame, for all cameras at once: only the nodes that samples are
    tied to need it, and the iterations keep the first linearisation's answer.
    """

    def __init__(
        self,
        cameras: list[Camera],
        cands: list[Candidates],
        rotations: np.ndarray,
        origins: np.ndarray,
        body: Body,
        probe_px: float,
    ) -> None:
        self.cameras, self.cands, self.rotations, self.origins = cameras, cands, rotations, origins
        self.body, self.probe_px = body, probe_px
        self._order = [np.argsort(_node_keys(c)) for c in cands]
        self.keys = [_node_keys(c)[o] for c, o in zip(cands, self._order)]  # sorted, per camera
        self._state = [
            np.full(len(c), -1, np.int8) for c in cands
        ]  # -1 untested, 0 off the outline, 1 on it

    def index(self, k: int, cand: Candidates) -> np.ndarray:
        """Return (C,) where each node of camera k's ``cand`` is among the first candidates.

        The nodes are all among its :attr:`keys`; the first candidates are the first
        linearisation's.
        """
        if cand is self.cands[k]:
            return np.arange(len(cand))
        return self._order[k][np.searchsorted(self.keys[k], _node_keys(cand))]

    def usable(self, index: list[np.ndarray]) -> list[np.ndarray]:
        """Per camera.

        True where its first-linearisation candidates ``index[k]`` are on the predicted outline.
        """
        todo = [
            np.flatnonzero(
                np.bincount(i[state[i] < 0], minlength=len(state))
            )  # each node once, in order
            for i, state in zip(index, self._state)
        ]
        if any(len(t) for t in todo):
            flags = rig_on_outline(
                self.cameras,
                [c.subset(t) for c, t in zip(self.cands, todo)],
                self.rotations,
                self.origins,
                self.body.semi_axes,
                self.body.lengths,
                self.probe_px,
            )
            for state, t, f in zip(self._state, todo, flags):
                state[t] = f
        return [state[i] == 1 for i, state in zip(index, self._state)]


def sample_spacing(table: np.ndarray) -> float:
    """Median pixel distance between consecutive samples of the same contour.

    REFERENCE_SPACING_PX if unknown.
    """
    if len(table) < 2:
        return REFERENCE_SPACING_PX
    same = (
        table['contour'][1:] == table['contour'][:-1]
        if 'contour' in (table.dtype.names or ())
        else np.ones(len(table) - 1, bool)
    )
    steps = np.hypot(np.diff(table['x']), np.diff(table['y']))[same]
    median = float(np.median(steps)) if len(steps) else 0.0
    return median if median > 0 else REFERENCE_SPACING_PX


def triangulate_centre(cameras: list[Camera], tables: list[np.ndarray]) -> np.ndarray | None:
    """Least-squares meeting point of the rays through each camera's contour centroid.

    None with < 2 cameras.
    """
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


def _always() -> bool:
    """Every search may run (step's default)."""
    return True
