"""walker_node: Rohr's MEMO walking-pedestrian tracker for one calibrated camera (Rohr §4-6).

Subscribes the camera's ``/<cam>/edges`` and ``/<cam>/person_box`` (from
contour_node) and ``/<cam>/camera_info`` (the studio's calibration is used
until a camera_info differs from it), joins edges and rectangle by header
stamp, runs :class:`memo_ros.core.walking.tracker.WalkingTracker` and
publishes ``/memo/joint_states`` (with ``gait_phase``), ``/memo/body_poses``,
``/memo/markers``, ``/memo/root_pose`` (pelvis with covariance),
``/memo/walker/measurement`` (the per-frame grid-search result) and
``/diagnostics``, all stamped with the frame's stamp.
"""

from __future__ import annotations

import sys
import time

from geometry_msgs.msg import PolygonStamped, PoseArray, PoseWithCovarianceStamped
import numpy as np
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, JointState, PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.rotations import rot_z
from memo_ros.core.vision.edges import EDGE_DTYPE
from memo_ros.core.walking.kalman import KalmanParams
from memo_ros.core.walking.similarity import SimilarityParams
from memo_ros.core.walking.tracker import DEPTH_FROM, TRACKING, WalkerSettings, WalkingTracker
from memo_ros.ros.body_messages import (
    PROCESSED_TOPIC,
    joint_state_message,
    marker_array_message,
    pose_array_message,
    processed_message,
    root_pose_message,
)
from memo_ros.ros.health import NodeHealth
from memo_ros.ros.messages import stamp_to_ns
from memo_ros.ros.node_main import run_node
from memo_ros.ros.params import Param, declare
from memo_ros.ros.pointcloud import pointcloud_to_array
from memo_ros.ros.studio_params import studio_from_node

MEASUREMENT_NAMES = ('X', 'Y', 'Z', 'pose', 'similarity', 'image', 'evaluations')
PENDING_LIMIT = 50  # frames waiting for their other half before the oldest is dropped
OUTPUT_DEPTH = 100  # the backlog after initialization leaves in a burst: keep it for slow readers

PARAMS: tuple[Param, ...] = (
    Param(
        'camera',
        '',
        "the studio camera to use (its topics /<camera>/...); '' = the studio's only camera",
        read_only=True,
    ),
    Param(
        'depth_from',
        'ground',
        "where the walker's depth comes from: ground = the rectangle's sole on the ground plane "
        "(world z = 0), the person's height measured with it; height = eq. 2-6 with "
        'person_height',
        choices=DEPTH_FROM,
    ),
    Param(
        'person_height',
        0.0,
        'depth_from height: assumed height H of the person for the rectangle (eq. 2-6), m; 0 = '
        "the walking model's mean head-top height",
        0.0,
        3.0,
    ),
    Param(
        'init_first',
        2,
        'first initialization image, counted from the first rectangle (Rohr: 2)',
        1,
        1000,
    ),
    Param('init_last', 14, 'last initialization image (Rohr: 14, about half a cycle)', 2, 1000),
    Param('step_x', 0.02, 'grid step in X (along the path), m', 0.002, 0.2),
    Param('step_y', 0.02, 'grid step in Y (height), m', 0.002, 0.2),
    Param(
        'step_pose',
        0.02,
        'grid step in pose, cycles (initialization searches the whole cycle)',
        0.005,
        0.1,
    ),
    Param(
        'init_half_x',
        0.2,
        'initialization: X varied +- this around the rectangle position, m',
        0.0,
        2.0,
    ),
    Param('init_half_y', 0.1, 'initialization: Y varied +- this, m', 0.0, 1.0),
    Param('max_half_x', 0.2, 'tracking: largest X half-window, m (Rohr: 2 dX = 40 cm)', 0.0, 2.0),
    Param('max_half_y', 0.1, 'tracking: largest Y half-window, m (Rohr: 2 dY = 20 cm)', 0.0, 1.0),
    Param(
        'max_half_pose',
        0.2,
        'tracking: largest pose half-window, cycles (Rohr: 2 dpose = 0.4)',
        0.0,
        0.45,
    ),
    Param(
        'window_sigmas', 1.0, 'tracking half-window in predicted standard deviations', 0.1, 10.0
    ),
    Param(
        'q_x_dot', 3.69e-4, "Kalman process noise of X', m^2/image^2 (Rohr: 3.69 cm^2)", 0.0, 1.0
    ),
    Param(
        'q_pose_dot',
        1.44e-4,
        "Kalman process noise of pose', 1/image^2 (Rohr: 0.000144)",
        0.0,
        0.1,
    ),
    Param('r_x', 0.04, 'Kalman measurement noise of X, m^2 (Rohr: 400 cm^2)', 1e-8, 10.0),
    Param('r_y', 0.01, 'Kalman measurement noise of Y, m^2 (Rohr: 100 cm^2)', 1e-8, 10.0),
    Param('r_pose', 0.04, 'Kalman measurement noise of pose (Rohr: 0.04)', 1e-8, 1.0),
    Param('c_l', 0.4, 'similarity (eq. 7): sigma_l = c_l l_M', 0.01, 10.0),
    Param('c_d', 0.5, 'similarity (eq. 7): sigma_d = c_d c_r l_M', 0.01, 10.0),
    Param('c_r', 0.2, 'search window half-width r = c_r l_M', 0.01, 5.0),
    Param('sigma_phi', 0.25, 'similarity (eq. 7): sigma of the angle difference, rad', 0.01, 3.0),
    Param('min_window', 2.0, 'smallest search window half-width, pixels', 0.1, 100.0),
    Param(
        'gradient_weight',
        False,
        'weight each match by its edge gradient magnitude (w_G of eq. 11)',
    ),
    Param(
        'reuse_distance',
        0.25,
        "reuse a pose's visible contours within this distance of where they were "
        'rendered, m (0 = render every pose of every search)',
        0.0,
        2.0,
    ),
    Param(
        'lost_after',
        10,
        'frames in a row without edges while tracking before the track is dropped',
        1,
        10000,
    ),
    Param(
        'queue_depth',
        300,
        'subscription queue depth (initialization takes longer than a frame)',
        1,
        100000,
        read_only=True,
    ),
    Param(
        'publish_measurement',
        True,
        'publish the per-frame grid-search result on /memo/walker/measurement',
    ),
)


def check_parameters(params: dict) -> None:
    """Refuse the combinations the per-parameter ranges cannot (ValueError with the reason)."""
    p = {q.name: q.default for q in PARAMS} | dict(params)
    if p['init_last'] <= p['init_first']:
        raise ValueError(
            f'init_last ({p["init_last"]}) must come after init_first ({p["init_first"]})'
        )


def walker_settings(params: dict, frame_rate: float) -> WalkerSettings:
    """Return the core settings from this node's parameters (defaults for any not given)."""
    check_parameters(params)
    p = {q.name: q.default for q in PARAMS} | dict(params)
    kalman = KalmanParams(
        q_x_dot=p['q_x_dot'],
        q_pose_dot=p['q_pose_dot'],
        r_x=p['r_x'],
        r_y=p['r_y'],
        r_pose=p['r_pose'],
    )
    similarity = SimilarityParams(
        c_l=p['c_l'],
        c_d=p['c_d'],
        c_r=p['c_r'],
        sigma_phi=p['sigma_phi'],
        min_window=p['min_window'],
        gradient_weight=p['gradient_weight'],
    )
    return WalkerSettings(
        depth_from=p['depth_from'],
        person_height=p['person_height'],
        frame_rate=frame_rate,
        init_first=p['init_first'],
        init_last=p['init_last'],
        step_x=p['step_x'],
        step_y=p['step_y'],
        step_pose=p['step_pose'],
        init_half_x=p['init_half_x'],
        init_half_y=p['init_half_y'],
        max_half_x=p['max_half_x'],
        max_half_y=p['max_half_y'],
        max_half_pose=p['max_half_pose'],
        window_sigmas=p['window_sigmas'],
        lost_after=p['lost_after'],
        reuse_distance=p['reuse_distance'],
        kalman=kalman,
        similarity=similarity,
    )


def box_corners(msg: PolygonStamped) -> np.ndarray | None:
    """Return the rectangle's corners (4, 2) or None when nobody is seen.

    ValueError for a malformed polygon.
    """
    points = msg.polygon.points
    if len(points) == 0:
        return None
    if len(points) != 4:
        raise ValueError(f'person_box has {len(points)} points, not 4')
    corners = np.array([[p.x, p.y] for p in points], float)
    if not np.all(np.isfinite(corners)) or np.ptp(corners[:, 1]) <= 0:
        raise ValueError('person_box has no height or non-finite corners')
    return corners


def edge_array(msg: PointCloud2) -> np.ndarray:
    """Return the edge-line table of an ``edges`` cloud; ValueError when fields are missing."""
    table = pointcloud_to_array(msg)
    missing = [
        n for n in ('x1', 'y1', 'x2', 'y2', 'magnitude') if n not in (table.dtype.names or ())
    ]
    if missing:
        raise ValueError(f'edges cloud lacks fields {", ".join(missing)}')
    out = np.zeros(len(table), EDGE_DTYPE)
    for name in ('x1', 'y1', 'x2', 'y2', 'magnitude'):
        out[name] = table[name]
    finite = np.isfinite(np.stack([out[n] for n in ('x1', 'y1', 'x2', 'y2')], 1)).all(1)
    return out[finite]


class WalkerNode(Node):
    """One camera's walking-pedestrian tracker."""

    def __init__(self, **kwargs) -> None:
        super().__init__('walker_node', **kwargs)
        self.params = declare(
            self,
            PARAMS,
            on_change=lambda: self.health.guard(self._on_parameters_set, 'parameter change')(),
            check=check_parameters,
        )
        self.studio = studio_from_node(self)
        name = self.params['camera'] or (
            self.studio.camera_names[0] if len(self.studio.cameras) == 1 else ''
        )
        if not name:
            raise ValueError(
                f'the studio has {len(self.studio.cameras)} cameras: set the camera parameter '
                f'(one of {", ".join(self.studio.camera_names)})'
            )
        self.studio_camera = self.studio.camera(name)
        self.camera_name = name
        self.settings = walker_settings(self.params, self.studio.frame_rate)
        self.health = NodeHealth(self, self.get_fully_qualified_name(), hardware_id=name)
        self.tracker: WalkingTracker | None = None
        self.camera = self.studio_camera  # the studio's calibration until a camera_info differs
        self._info_raw: tuple | None = None
        self.pending: dict[int, dict] = {}
        self.last_stamp: int | None = None
        reliable = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE,
            history=HistoryPolicy.KEEP_LAST,
            depth=self.params['queue_depth'],
        )
        self.create_subscription(
            CameraInfo,
            f'/{name}/camera_info',
            self.health.guard(self._on_camera_info, 'camera_info callback'),
            QoSProfile(
                reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=10
            ),
        )
        self.create_subscription(
            PointCloud2,
            f'/{name}/edges',
            self.health.guard(self._on_edges, 'edges callback'),
            reliable,
        )
        self.create_subscription(
            PolygonStamped,
            f'/{name}/person_box',
            self.health.guard(self._on_box, 'person_box callback'),
            reliable,
        )
        self.pub_joints = self.create_publisher(JointState, '/memo/joint_states', OUTPUT_DEPTH)
        self.pub_poses = self.create_publisher(PoseArray, '/memo/body_poses', OUTPUT_DEPTH)
        self.pub_markers = self.create_publisher(MarkerArray, '/memo/markers', OUTPUT_DEPTH)
        self.pub_root = self.create_publisher(
            PoseWithCovarianceStamped, '/memo/root_pose', OUTPUT_DEPTH
        )
        self.pub_measurement = self.create_publisher(
            JointState, '/memo/walker/measurement', OUTPUT_DEPTH
        )
        self.pub_processed = self.create_publisher(Header, PROCESSED_TOPIC, OUTPUT_DEPTH)
        self.get_logger().info(
            f'walking tracker on {name}: depth {self._depth_source()}, '
            f'initialization images {self.settings.init_first}-{self.settings.init_last}'
        )

    def _depth_source(self) -> str:
        """Say where the depth comes from, for the log."""
        if self.settings.depth_from == 'ground':
            return "from the ground plane (z = 0), the person's height measured"
        height = (
            f'{self.settings.person_height:.3f} m'
            if self.settings.person_height
            else "the walking model's mean head-top height"
        )
        return f'from the assumed height H = {height} (eq. 2-6)'

    # ------------------------------------------------------------ inputs
    def _on_parameters_set(self) -> None:
        self.settings = walker_settings(self.params, self.studio.frame_rate)
        self.tracker = None  # rebuilt with the new settings at the next frame
        self.health.note('reconfigured', 'parameters changed: walker restarts its initialization')

    def _on_camera_info(self, msg: CameraInfo) -> None:
        raw = (msg.width, msg.height, tuple(msg.k), tuple(msg.d), msg.distortion_model)
        if raw == self._info_raw:
            return
        self._info_raw = raw
        try:
            camera = Camera.from_camera_info_fields(
                msg.width,
                msg.height,
                msg.distortion_model,
                msg.d,
                msg.k,
                msg.r,
                msg.p,
                msg.header.frame_id,
                name=self.camera_name,
                R_world_cam=self.studio_camera.R_world_cam,
                t_world_cam=self.studio_camera.t_world_cam,
            )
        except ValueError as exc:
            self.health.note('bad_camera_info', f'camera_info refused: {exc}')
            return
        old = self.camera
        if (
            (camera.width, camera.height, camera.distortion_model)
            == (old.width, old.height, old.distortion_model)
            and np.allclose(camera.K, old.K)
            and np.allclose(camera.D, old.D)
        ):
            return
        self.health.note(
            'camera_info_changed',
            'camera_info differs from the calibration in use: the walker '
            'takes it and restarts its initialization',
        )
        self.camera = camera
        self.tracker = None

    def _on_edges(self, msg: PointCloud2) -> None:
        self._arrive(msg.header.stamp, 'edges', msg)

    def _on_box(self, msg: PolygonStamped) -> None:
        self._arrive(msg.header.stamp, 'box', msg)

    def _arrive(self, stamp, kind: str, msg) -> None:
        """Join the two halves of a frame by stamp; process it once both are here."""
        stamp_ns = stamp_to_ns(stamp)
        entry = self.pending.setdefault(stamp_ns, {})
        if kind in entry:
            self.health.count('frames_in')
            self.health.drop(
                'duplicate_stamp', f'a second {kind} message with the stamp of an earlier one'
            )
            return
        entry[kind] = msg
        if len(entry) < 2:
            if len(self.pending) > PENDING_LIMIT:
                oldest = min(self.pending)
                self.pending.pop(oldest)
                self.health.count('frames_in')
                self.health.drop('unpaired', 'edges or person_box of a frame never arrived')
            return
        del self.pending[stamp_ns]
        for older in [
            s for s in self.pending if s < stamp_ns
        ]:  # their other half will not come now
            self.pending.pop(older)
            self.health.count('frames_in')
            self.health.drop('unpaired', 'edges or person_box of a frame never arrived')
        self.health.count('frames_in')
        self._process(stamp_ns, entry['edges'], entry['box'])

    # ---------------------------------------------------------- processing
    def _process(self, stamp_ns: int, edges_msg: PointCloud2, box_msg: PolygonStamped) -> None:
        """Track one joined frame, then say it is done (whatever came of it)."""
        outcome = self._walk(stamp_ns, edges_msg, box_msg)
        self.pub_processed.publish(processed_message(stamp_ns, outcome))

    def _walk(self, stamp_ns: int, edges_msg: PointCloud2, box_msg: PolygonStamped) -> str:
        if self.last_stamp is not None and stamp_ns < self.last_stamp:
            self.tracker = None
            self.health.note(
                'time_jump_resets', 'timestamps went backwards (bag loop?): walker reset'
            )
        elif self.last_stamp is not None and stamp_ns == self.last_stamp:
            self.health.drop('duplicate_stamp', 'frame with the stamp of the previous one')
            return 'duplicate_stamp'
        try:
            corners = box_corners(box_msg)
            edges = edge_array(edges_msg)
        except ValueError as exc:
            self.health.drop('bad_input', f'malformed input: {exc}')
            return 'bad_input'
        self.last_stamp = stamp_ns
        if self.tracker is None:
            self.tracker = WalkingTracker(self.studio.body, self.camera, self.settings)
        start = time.perf_counter()
        result = self.tracker.step(stamp_ns, corners, edges)
        elapsed = time.perf_counter() - start
        self._account(result, elapsed)
        if self.params['publish_measurement']:
            self._publish_measurement(result)
        if result.estimate is not None and self.tracker.state == TRACKING:
            self._publish_estimate(stamp_ns, result.estimate, result.covariance)
        return str(self.tracker.state)

    def _account(self, result, elapsed: float) -> None:
        """Counters per outcome: every frame without an estimate is counted under its reason."""
        event = result.event
        reasons = {
            'no_person': 'no person in the frame',
            'stale_stamp': 'frame not newer than the last tracked one',
            'bad_box': 'the rectangle gives no 3D position (eq. 2-6): no height, or behind the '
            'camera',
        }
        if event in reasons:
            self.health.drop(event, reasons[event])
            return
        self.health.count('processed')
        if event in ('init_image', 'init_skipped'):
            self.health.count('initializing')
        elif event in ('lost', 'init_interrupted'):
            self.health.note(
                event,
                'track lost: no edges for too long'
                if event == 'lost'
                else 'nobody in the frame during initialization: starting again',
            )
        else:
            self.health.count(event)  # started, tracked, coasted
        self.health.set('state', self.tracker.state)
        self.health.set('last_frame_ms', f'{1000 * elapsed:.1f}')
        self.health.set('last_evaluations', result.evaluations)
        self.health.set('last_renderings', result.renderings)
        if result.choice is not None:
            c = result.choice
            self.health.set(
                'init_line', f'{c.rule}: {c.counts[0]} on the chosen line, {c.counts[1]} displaced'
            )
            body = ''
            if self.tracker.body_height is not None:
                self.health.set('body_height', f'{self.tracker.body_height:.3f}')
                body = f", the person's height {self.tracker.body_height:.3f} m"
            self.health.set('depth', f'{result.estimate[4]:.3f}')
            self.get_logger().info(
                f'initialized: pose line chosen by {c.rule} ({c.counts[0]} estimates on it, '
                f'{c.counts[1]} half a cycle away); pelvis at world y = '
                f'{result.estimate[4]:.3f} m ({self.settings.depth_from}){body}'
            )
        self.health.ok()

    # ------------------------------------------------------------- outputs
    def _publish_measurement(self, result) -> None:
        for (
            stamp_ns,
            image,
            m,
            depth,
        ) in result.measurements:  # init images searched late keep their stamps
            values = (
                m.X,
                m.Y,
                depth,
                float(np.mod(m.pose, 1.0)),
                m.similarity,
                image,
                float(m.evaluations),
            )
            self.pub_measurement.publish(joint_state_message(stamp_ns, MEASUREMENT_NAMES, values))

    def _publish_estimate(self, stamp_ns: int, p: np.ndarray, P: np.ndarray) -> None:
        tracker = self.tracker
        q = tracker.coordinates(p)
        qd = tracker.velocities(p)
        rate = self.settings.frame_rate
        names = list(self.studio.body.coordinate_names) + ['gait_phase']
        self.pub_joints.publish(
            joint_state_message(
                stamp_ns,
                names,
                list(q) + [float(np.mod(p[6], 1.0))],
                list(qd) + [float(p[7] * rate)],
            )
        )
        rotations, origins = self.studio.body.forward_kinematics(q)
        self.pub_poses.publish(pose_array_message(stamp_ns, rotations, origins))
        self.pub_markers.publish(
            marker_array_message(stamp_ns, self.studio.body, rotations, origins)
        )
        cov = np.zeros((6, 6))
        cov[0, 0], cov[2, 2] = P[0, 0], P[2, 2]  # X along the path, Y vertical; depth Z is held
        cov[1, 1] = P[4, 4]
        self.pub_root.publish(
            root_pose_message(stamp_ns, rot_z(tracker.heading or 0.0), origins[0], cov)
        )


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run memo_ros walker_node``."""
    return run_node('walker_node', WalkerNode, args)


if __name__ == '__main__':
    sys.exit(main())
