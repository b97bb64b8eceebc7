"""Rohr's MEMO walker (§4-6) over an image sequence.

Initialization, then incremental Kalman estimation.

Feed :meth:`WalkingTracker.step` every frame's stamp, the person's enclosing rectangle (or None)
and the edge lines.  Images are numbered from the first rectangle by their stamps.  Initialization
(images ``init_first``.. ``init_last``, Rohr's 2-14): per image the rectangle gives a 3D position
(``depth_from='ground'``: its sole on the ground plane, ground.py; ``'height'``: eq. 2-6 with the
assumed H) and a grid search over the whole cycle and X, Y around it gives a single estimate; at
the end the two-lines rule and linear regression give the starting state.  From the ground, each
image's depth is its sole plus the offset of the model's own rectangle posed on the chosen line,
and the person's height is measured (the median over the images).  Tracking: the Kalman
prediction (eq. 14, 15) centres a grid search whose half-widths are ``window_sigmas`` standard
deviations of the predicted covariance (at least one grid step, at most the paper's intervals), and
the best grid point is the measurement (eq. 16-18).  The rectangle is not needed while tracking
(Rohr §6: no change detection then).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from memo_ros.core.geometry.body import Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.walking.ground import position_on_ground, rectangle_offsets
from memo_ros.core.walking.initialisation import (
    LineChoice,
    SingleEstimate,
    starting_state,
    two_lines,
    wrap,
)
from memo_ros.core.walking.kalman import KalmanParams, WalkingKalman
from memo_ros.core.walking.position import box_midpoints, position_from_box
from memo_ros.core.walking.search import SearchResult, WalkerModel, grid_offsets
from memo_ros.core.walking.similarity import SimilarityParams, edge_table

WAITING, INITIALIZING, TRACKING = 'waiting', 'initializing', 'tracking'
DEPTH_FROM = ('ground', 'height')  # the sole on the known ground, or Rohr's assumed height H


@dataclass(frozen=True)
class WalkerSettings:
    """Everything the walker needs besides the body and the camera."""

    depth_from: str = 'ground'  # 'ground': the sole on the ground plane; 'height': eq. 2-6 with H
    ground_z: float = 0.0  # world z of the ground plane (DESIGN.md: 0)
    person_height: float = (
        0.0  # assumed H (m) for eq. 2-6; 0: the walking model's mean head-top height
    )
    frame_rate: float = 25.0  # images per second (numbers images from the stamps)
    init_first: int = 2  # first and last initialization image (Rohr §6: 2-14)
    init_last: int = 14
    step_x: float = 0.02  # grid steps: 2 cm, 2 cm, 0.02 (Rohr §6)
    step_y: float = 0.02
    step_pose: float = 0.02
    init_half_x: float = 0.2  # initialization: X, Y varied around the rectangle's position
    init_half_y: float = 0.1
    max_half_x: float = 0.2  # tracking windows at most the paper's 2 dX = 40 cm, 2 dY = 20 cm,
    max_half_y: float = 0.1  # 2 dpose = 0.4
    max_half_pose: float = 0.2
    window_sigmas: float = 1.0  # tracking half-width = this many predicted standard deviations
    lost_after: int = 10  # consecutive frames without edges before the track is dropped
    reuse_distance: float = (
        0.25  # m: a pose's visible contours are reused this close to their rendering
    )
    kalman: KalmanParams = field(default_factory=KalmanParams)
    similarity: SimilarityParams = field(default_factory=SimilarityParams)


@dataclass
class StepResult:
    """What one frame produced."""

    stamp_ns: int
    state: str  # WAITING, INITIALIZING or TRACKING after this frame
    image: float | None = None  # image number
    measurement: SearchResult | None = None  # the last single-image estimate made in this step
    measurements: list = field(
        default_factory=list
    )  # every one: (stamp_ns, image, SearchResult, Z)
    estimate: np.ndarray | None = None  # Kalman state p (8,) when tracking
    covariance: np.ndarray | None = None  # its covariance (8, 8)
    box_position: np.ndarray | None = None  # eq. 2-6 sole position (3,), when a rectangle was used
    choice: LineChoice | None = None  # the two-lines decision, on the frame initialization ended
    event: str = ''  # 'started', 'tracked', 'coasted', 'lost', 'no_person', 'bad_box',
    # 'init_image', 'init_skipped', 'init_interrupted', 'stale_stamp'
    evaluations: int = 0
    renderings: int = 0
    seconds: float = 0.0


class WalkingTracker:
    """Initialization and incremental estimation for one walker and one camera."""

    def __init__(self, body: Body, camera: Camera, settings: WalkerSettings | None = None) -> None:
        self.settings = settings or WalkerSettings()
        self.model = WalkerModel(
            body, camera, self.settings.similarity, reuse_distance=self.settings.reuse_distance
        )
        if self.settings.depth_from not in DEPTH_FROM:
            raise ValueError(
                f'depth_from must be one of {", ".join(DEPTH_FROM)}, '
                f'not {self.settings.depth_from!r}'
            )
        self.height = self.settings.person_height or self.model.head_top_height()
        self.body_height: float | None = None  # the person's standing height, measured (ground)
        self.reset()

    def reset(self) -> None:
        """Forget everything: wait for the next rectangle to start a new initialization."""
        self.state = WAITING
        self.first_stamp: int | None = None
        self.last_stamp: int | None = None
        self.pending: list[
            tuple[int, float, np.ndarray, np.ndarray, float]
        ] = []  # (stamp, image, sole, edges, the rectangle's height H or 0)
        self.estimates: list[SingleEstimate] = []
        self.soles: list[tuple[np.ndarray, float]] = []  # per estimate: sole, rectangle's H
        self.heading: float | None = None
        self.filter: WalkingKalman | None = None
        self.missed = 0
        self.model.clear_cache()

    # ------------------------------------------------------------------ step
    def image_number(self, stamp_ns: int) -> float:
        """Image number from the stamp: 1 for the first rectangle's frame."""
        if self.first_stamp is None:
            raise RuntimeError('image numbers count from the first rectangle: none seen yet')
        return 1.0 + round((stamp_ns - self.first_stamp) * 1e-9 * self.settings.frame_rate)

    def step(self, stamp_ns: int, box_corners, edges) -> StepResult:
        """Process one frame.

        ``box_corners`` (4, 2) pixels or None, ``edges`` EDGE_DTYPE or (E, 5).
        """
        edges = edge_table(edges)
        if self.state == TRACKING:
            return self._track(stamp_ns, edges)
        if box_corners is None or len(box_corners) == 0:
            if self.state == INITIALIZING:
                self.reset()
                return StepResult(stamp_ns, self.state, event='init_interrupted')
            return StepResult(stamp_ns, self.state, event='no_person')
        if self.state == WAITING:
            self.state, self.first_stamp = INITIALIZING, stamp_ns
        return self._initialize(stamp_ns, np.asarray(box_corners, float), edges)

    # -------------------------------------------------------- initialization
    def _initialize(self, stamp_ns: int, corners: np.ndarray, edges: np.ndarray) -> StepResult:
        s = self.settings
        image = self.image_number(stamp_ns)
        self.last_stamp = stamp_ns
        if image < s.init_first:
            return StepResult(stamp_ns, self.state, image, event='init_skipped')
        bottom, top = box_midpoints(corners)
        try:
            if s.depth_from == 'ground':  # eq. 3-5 with the sole on the ground: H is measured
                ground = position_on_ground(self.model.camera, bottom, top, s.ground_z)
                sole, rect_height = ground.sole, ground.height
            else:  # eq. 2-6 with the assumed H
                sole = position_from_box(self.model.camera, bottom, top, self.height).sole
                rect_height = 0.0
        except ValueError:  # a rectangle no standing person can make
            return StepResult(stamp_ns, self.state, image, event='bad_box')
        self.pending.append((stamp_ns, image, sole, edges, rect_height))
        result = StepResult(stamp_ns, self.state, image, box_position=sole, event='init_image')
        if self.heading is None:
            travel = self.pending[-1][2][0] - self.pending[0][2][0]
            if abs(travel) < 0.05 and image < s.init_last:
                return result  # direction not known yet: keep the frame
            self.heading = 0.0 if travel >= 0 else np.pi
        for (
            stamp,
            number,
            position,
            frame_edges,
            rect_height,
        ) in self.pending:  # whole-cycle search per image (§5.1)
            found = self.model.search(
                frame_edges,
                position[0],
                position[2],
                position[1],
                np.arange(0.0, 1.0, s.step_pose),
                grid_offsets(s.init_half_x, s.step_x),
                grid_offsets(s.init_half_y, s.step_y),
                self.heading,
            )
            depth = float(position[1])
            if rect_height:  # provisional: the pose may yet turn out legs-swapped
                depth = self._ground_depth(found.X, position, rect_height, found.pose)[0]
            self.estimates.append(
                SingleEstimate(number, found.X, found.Y, depth, found.pose, found.similarity)
            )
            self.soles.append((position, rect_height))
            result.measurement = found
            result.measurements.append((stamp, number, found, depth))
            result.evaluations += found.evaluations
            result.renderings += found.renderings
            result.seconds += found.seconds
        self.pending = []
        if image >= s.init_last:
            self._start_tracking(image, result)
        return result

    def _start_tracking(self, image: float, result: StepResult) -> None:
        e = self.estimates
        choice = two_lines(
            np.array([x.image for x in e]),
            np.array([x.pose for x in e]),
            np.array([x.similarity for x in e]),
            self._slope_range(),
        )
        if self.settings.depth_from == 'ground':
            heights = []
            for estimate, (sole, rect_height) in zip(e, self.soles):
                pose = choice.phase0 + choice.slope * estimate.image  # on the chosen line
                estimate.Z, height = self._ground_depth(estimate.X, sole, rect_height, pose)
                heights.append(height)
            self.body_height = float(np.median(heights))
        p0 = starting_state(e, image, choice)
        self.filter = WalkingKalman(p0, self.settings.kalman)
        self.state = TRACKING
        self.missed = 0
        result.state, result.choice, result.event = TRACKING, choice, 'started'
        result.estimate, result.covariance = self.filter.p.copy(), self.filter.P.copy()

    def _ground_depth(
        self, X: float, sole: np.ndarray, rect_height: float, pose: float
    ) -> tuple[float, float]:
        """Pelvis depth and standing height from a rectangle's sole on the ground and its H.

        The model posed there has its own rectangle: its pelvis minus its sole is the offset from
        the rectangle's sole (the near rim of the lower foot) to the pelvis, and the measured over
        its rectangle's H scales its standing height to the person's.
        """
        s = self.settings
        depth = float(sole[1])
        for _ in range(2):  # the offset barely depends on the depth: one refinement
            q = self.model.coordinates(X, s.ground_z, depth, pose, self.heading or 0.0)
            model = rectangle_offsets(
                self.model.camera,
                self.model.body,
                *self.model.body.forward_kinematics(q),
                s.ground_z,
            )
            scale = rect_height / model.rectangle_height
            offset = model.pelvis_from_sole[1] * scale  # the person: the model scaled
            depth = float(sole[1] + offset)
        return depth, model.standing_height * scale

    def _slope_range(self) -> tuple[float, float]:
        """Plausible pose per image: 0.25 to 2 cycles per second."""
        rate = self.settings.frame_rate
        return 0.25 / rate, 2.0 / rate

    # -------------------------------------------------------------- tracking
    def _track(self, stamp_ns: int, edges: np.ndarray) -> StepResult:
        s = self.settings
        kalman, heading = self.filter, self.heading
        if self.last_stamp is None or kalman is None or heading is None:
            raise RuntimeError('tracking before the initialization ended')  # _start_tracking sets
        dt = round((stamp_ns - self.last_stamp) * 1e-9 * s.frame_rate)
        if dt < 1:
            return StepResult(stamp_ns, self.state, event='stale_stamp')
        self.last_stamp = stamp_ns
        image = self.image_number(stamp_ns)
        p, P = kalman.predict(dt)  # eq. 14, 15
        if len(edges) == 0:
            self.missed += 1
            if self.missed > s.lost_after:
                self.reset()
                return StepResult(stamp_ns, self.state, image, event='lost')
            return StepResult(
                stamp_ns, self.state, image, estimate=p, covariance=P, event='coasted'
            )
        self.missed = 0
        sd = np.sqrt(np.maximum(np.diag(P), 0.0))
        half_x = np.clip(s.window_sigmas * sd[0], s.step_x, s.max_half_x)
        half_y = np.clip(s.window_sigmas * sd[2], s.step_y, s.max_half_y)
        half_pose = np.clip(s.window_sigmas * sd[6], s.step_pose, s.max_half_pose)
        # centred on the prediction rounded to the pose lattice, so renderings carry over between
        # frames
        poses = s.step_pose * np.round(p[6] / s.step_pose) + grid_offsets(half_pose, s.step_pose)
        found = self.model.search(
            edges,
            p[0],
            p[2],
            p[4],
            poses,
            grid_offsets(half_x, s.step_x),
            grid_offsets(half_y, s.step_y),
            heading,
        )
        z = np.array([found.X, found.Y, p[4], p[6] + wrap(found.pose - p[6])])
        p, P = kalman.update(z)  # eq. 16-18
        return StepResult(
            stamp_ns,
            self.state,
            image,
            found,
            [(stamp_ns, image, found, float(p[4]))],
            p,
            P,
            event='tracked',
            evaluations=found.evaluations,
            renderings=found.renderings,
            seconds=found.seconds,
        )

    # ---------------------------------------------------------------- output
    def coordinates(self, p: np.ndarray) -> np.ndarray:
        """Generalized coordinates of a state p (8,)."""
        return self.model.coordinates(p[0], p[2], p[4], np.mod(p[6], 1.0), self.heading or 0.0)

    def velocities(self, p: np.ndarray, eps: float = 1e-4) -> np.ndarray:
        """Time derivatives (per second) of the generalized coordinates of state p."""
        rate = self.settings.frame_rate
        ahead = p + eps * np.array([p[1], 0, p[3], 0, p[5], 0, p[7], 0])
        return (self.coordinates(ahead) - self.coordinates(p)) / eps * rate
