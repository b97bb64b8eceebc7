"""selector_node: per frame and part, which cameras the tracker may use (Kakadiaris & Metaxas §4).

The first ``/<cam>/camera_info`` with a new header stamp t starts frame t
(one assignment per stamp).  The newest ``/memo/joint_states`` posterior older
than t is predicted to t with the tracker's motion model; the core's
:class:`CameraSelector` renders the predicted body per camera for the
visibility index and the observability and publishes the
:class:`Assignment` on ``/memo/camera_assignment`` stamped t.  Without a
recent posterior every live camera is assigned to every part (mode
``all_cameras``).  A camera whose newest camera_info and contours stamps are
older than t by more than ``camera_timeout``, or whose contour_node stopped
delivering (``contours_timeout``), is excluded until it comes back
(stamps, not arrival times, so a bag replays alike at any rate).
"""

from __future__ import annotations

from collections import deque
import struct
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, JointState, PointCloud2

from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import PART_NAMES
from memo_ros.core.geometry.camera import intrinsics_problem
from memo_ros.core.latency.decimation import DecimationSchedule
from memo_ros.core.multiview.anatomy import pose_problem, studio_volume
from memo_ros.core.multiview.motion import (
    EXTRA_STATE_NAMES,
    ConstantVelocity,
    named_values_problem,
)
from memo_ros.core.multiview.selection import (
    MAX_CAMERAS,
    NORMS,
    Assignment,
    CameraLiveness,
    CameraSelector,
    SelectionSettings,
)
from memo_ros.ros.assignment_messages import assignment_to_message
from memo_ros.ros.decimation_messages import count_shed, follow_decimation
from memo_ros.ros.health import NodeHealth
from memo_ros.ros.messages import stamp_to_ns
from memo_ros.ros.node_main import run_node
from memo_ros.ros.params import Param, declare
from memo_ros.ros.studio_params import studio_from_node

ASSIGNMENT_TOPIC = '/memo/camera_assignment'
POSTERIOR_TOPIC = '/memo/joint_states'
POSTERIOR_HISTORY = 20
K_TOLERANCE = 1e-6  # relative difference allowed between a camera_info's K and the studio's

PARAMS = (
    Param(
        'vi_threshold',
        0.0,
        'a part is visible from a camera when its visibility index (visible / unoccluded '
        'projected area) is at least this; 0: every camera it projects into (Kakadiaris §4 uses '
        '0.2, which '
        'drops partial views the tracker needs)',
        0.0,
        1.0,
    ),
    Param(
        'max_cameras_per_part',
        0,
        'most cameras assigned to one part, best observability first; 0: every visible camera',
        0,
        MAX_CAMERAS,
    ),
    Param(
        'render_scale',
        0.25,
        "resolution of the visibility label images as a fraction of each camera's",
        0.05,
        1.0,
    ),
    Param(
        'observability_norm',
        'norm_of_sum',
        "how a part's predicted contour-node image motion is combined: "
        "the paper's norm of the sum, or the sum of the norms (does not cancel for a part "
        'spinning about its '
        'own axis)',
        choices=NORMS,
    ),
    Param(
        'camera_timeout',
        0.5,
        'a camera whose newest camera_info and contours stamps are older than the frame by '
        'more than this many seconds is excluded until it comes back',
        0.01,
        3600.0,
    ),
    Param(
        'require_contours',
        True,
        'a camera counts alive only while its contour_node delivers too; false: its '
        'camera_info alone keeps it alive (the selector run without contour nodes)',
    ),
    Param(
        'contours_timeout',
        2.0,
        'with require_contours: a camera whose contour_node delivered nothing for this '
        'long (wall time) while its camera_info went on for camera_timeout is excluded, s',
        0.05,
        3600.0,
    ),
    Param(
        'max_posterior_age',
        0.5,
        'a /memo/joint_states posterior older than the frame by more than this many '
        'seconds is not predicted from: every live camera is assigned to every part instead',
        0.0,
        3600.0,
    ),
    Param(
        'summary_every',
        30,
        "log a one-line summary at info level every this many frames (each frame's "
        'selection is logged at debug level)',
        1,
        1_000_000,
    ),
)


def selection_settings(params: dict) -> SelectionSettings:
    """Return the core selector's settings from this node's parameters.

    Defaults for any not given.
    """
    p = {q.name: q.default for q in PARAMS} | dict(params)
    return SelectionSettings(
        vi_threshold=p['vi_threshold'],
        max_cameras_per_part=p['max_cameras_per_part'],
        render_scale=p['render_scale'],
        observability_norm=p['observability_norm'],
        camera_timeout_s=p['camera_timeout'],
    )


def header_stamp_ns(cdr: bytes) -> int | None:
    """Return the header stamp of a serialized message that starts with std_msgs/Header.

    None if too short.
    """
    if len(cdr) < 12:
        return None
    endian = '<' if cdr[1] & 1 else '>'  # CDR encapsulation: 0x0001 little, 0x0000 big endian
    sec, nanosec = struct.unpack_from(endian + 'iI', cdr, 4)
    return sec * 1_000_000_000 + nanosec


def selection_line(assignment: Assignment) -> str:
    """One line: each part's selected cameras, best first ('-' = unobserved)."""
    return ' '.join(
        f'{p}={"+".join(assignment.cameras_for(i)) or "-"}' for i, p in enumerate(PART_NAMES)
    )


class SelectorNode(Node):
    """Active camera selection for the tracker, one assignment per camera frame stamp."""

    def __init__(self, **kwargs) -> None:
        super().__init__('selector_node', **kwargs)
        # the core refuses combinations the per-parameter ranges cannot, with the reason
        self.params = declare(
            self,
            PARAMS,
            on_change=lambda: self.health.guard(self._on_parameters_set, 'parameter change')(),
            check=selection_settings,
        )
        self.settings = selection_settings(self.params)
        self.studio: Studio = studio_from_node(self)
        self.body = self.studio.body
        self.names = self.studio.camera_names
        self.selector = CameraSelector(self.body, self.studio.cameras, self.settings)
        self.motion = ConstantVelocity(self.body)
        self.volume = studio_volume(self.studio.cameras)
        self.coordinate_index = {n: i for i, n in enumerate(self.body.coordinate_names)}
        self.liveness = CameraLiveness(
            list(self.names),
            self.settings.camera_timeout_s,
            self.params['require_contours'],
            self.params['contours_timeout'],
        )
        self.health = NodeHealth(self, self.get_fully_qualified_name(), hardware_id='selector')
        self.posteriors: deque[tuple[int, np.ndarray, np.ndarray]] = deque(
            maxlen=POSTERIOR_HISTORY
        )
        self.info_stamp: dict[str, int] = {}
        self.checked_info: dict[str, tuple] = {}  # each camera's last intrinsics found fine
        self.last_frame_ns: int | None = None
        self.schedule = DecimationSchedule()  # the frames the graph keeps (the tracker's word)
        self.was_alive = dict.fromkeys(self.names, True)
        self.frame_ms: deque[float] = deque(maxlen=100)
        reliable = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=10
        )
        for cam in self.names:
            self.create_subscription(
                CameraInfo,
                f'/{cam}/camera_info',
                self.health.guard(
                    lambda msg, cam=cam: self._on_camera_info(cam, msg),
                    f'{cam}/camera_info callback',
                ),
                reliable,
            )
            self.create_subscription(
                PointCloud2,
                f'/{cam}/contours',
                self.health.guard(
                    lambda data, cam=cam: self._on_contours(cam, data), f'{cam}/contours callback'
                ),
                reliable,
                raw=True,
            )
        self.create_subscription(
            JointState,
            POSTERIOR_TOPIC,
            self.health.guard(self._on_joint_states, 'joint_states callback'),
            reliable,
        )
        self.publisher = self.create_publisher(DiagnosticArray, ASSIGNMENT_TOPIC, reliable)
        follow_decimation(self, self.schedule, self.health)
        self.health.set('cameras', ','.join(self.names))
        self.get_logger().info(
            f'studio {self.studio.name}: cameras {", ".join(self.names)}; '
            f'vi_threshold {self.settings.vi_threshold}, '
            f'{self.settings.max_cameras_per_part or "every visible"} camera(s) per part at most, '
            f'{self.settings.observability_norm}'
        )

    # ------------------------------------------------------------ parameters
    def _on_parameters_set(self) -> None:
        self.settings = selection_settings(self.params)
        self.selector = CameraSelector(self.body, self.studio.cameras, self.settings)
        self.liveness.timeout_s = self.settings.camera_timeout_s
        self.liveness.require_contours = self.params['require_contours']
        self.liveness.contours_timeout_s = self.params['contours_timeout']
        self.health.note('reconfigured', 'parameters changed: selector rebuilt')

    # ---------------------------------------------------------------- inputs
    def _on_contours(self, cam: str, data: bytes) -> None:
        stamp = header_stamp_ns(data)
        if stamp is None:
            self.health.drop('bad_contours', f'{cam}/contours: message too short for a header')
            return
        self.liveness.seen(cam, stamp, 'contours')

    def _on_joint_states(self, msg: JointState) -> None:
        self.health.count('joint_states_in')
        stamp = stamp_to_ns(msg.header.stamp)
        names, pos, vel = (
            list(msg.name),
            np.asarray(msg.position, float),
            np.asarray(msg.velocity, float),
        )
        if len(pos) != len(names) or (len(vel) and len(vel) != len(names)):
            self.health.drop(
                'bad_joint_state',
                f'joint_states: {len(names)} names, {len(pos)} positions, {len(vel)} velocities',
            )
            return
        problem = named_values_problem(names, pos)
        if problem:
            self.health.drop('bad_joint_state', f'joint_states refused: {problem}')
            return
        unknown = [
            n for n in names if n not in self.coordinate_index and n not in EXTRA_STATE_NAMES
        ]
        if unknown:
            self.health.drop(
                'unknown_joint_names',
                f'joint_states: unknown coordinates {", ".join(unknown[:5])}',
            )
            return
        missing = set(self.coordinate_index) - set(names)
        if missing:
            self.health.drop(
                'missing_coordinates', f'joint_states: missing {", ".join(sorted(missing)[:5])}'
            )
            return
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            self.health.drop(
                'nonfinite_joint_state', 'joint_states: NaN or infinite position or velocity'
            )
            return
        if not len(vel):
            vel = np.zeros(len(names))
            self.health.note(
                'no_velocity', 'joint_states without velocities: predicted as standing still'
            )
        q = np.zeros(self.body.n_coordinates)
        qdot = np.zeros(self.body.n_coordinates)
        for name, p, v in zip(names, pos, vel):
            i = self.coordinate_index.get(name)
            if i is not None:
                q[i], qdot[i] = p, v
        problem = pose_problem(self.body, q, self.volume)
        if problem:  # the last good posteriors stay
            self.health.drop('absurd_joint_state', f'joint_states refused: {problem}')
            return
        if self.posteriors and stamp <= self.posteriors[-1][0]:
            if stamp == self.posteriors[-1][0]:
                self.health.drop(
                    'stamp_not_newer', 'joint_states with the stamp of the previous one'
                )
                return
            self.posteriors.clear()
            self.health.note(
                'time_jump_resets', 'joint_states stamps went backwards (bag loop?): history reset'
            )
        self.posteriors.append((stamp, q, qdot))

    def _check_camera_info(self, cam: str, msg: CameraInfo) -> tuple[str, str] | None:
        """Return (reason, message) when a camera_info is unusable or contradicts the studio.

        That is, the studio's calibration of that camera; None when it is fine.
        """
        k = np.asarray(msg.k, float)
        problem = intrinsics_problem(msg.width, msg.height, msg.distortion_model, msg.d, k)
        if problem:
            return ('bad_camera_info', f'{cam}/camera_info does not make a camera: {problem}')
        model = self.studio.camera(cam)
        problem = intrinsics_problem(msg.width, msg.height, msg.distortion_model, msg.d, k, model)
        if problem:
            return ('camera_info_mismatch', f'{cam}/camera_info: {problem}')
        if (msg.width, msg.height) != (model.width, model.height) or not np.allclose(
            k, model.K.ravel(), rtol=K_TOLERANCE, atol=K_TOLERANCE
        ):
            return (
                'camera_info_mismatch',
                f'{cam}/camera_info ({msg.width}x{msg.height}, K {k.tolist()}) '
                'differs from the studio calibration',
            )
        return None

    def _on_camera_info(self, cam: str, msg: CameraInfo) -> None:
        self.health.count('camera_info_in')
        stamp = stamp_to_ns(msg.header.stamp)
        # a camera sends the same intrinsics with every frame: checked again only when they change
        intrinsics = (msg.width, msg.height, msg.distortion_model, bytes(msg.d), bytes(msg.k))
        if self.checked_info.get(cam) != intrinsics:
            problem = self._check_camera_info(cam, msg)
            if problem:
                self.health.drop(*problem)
                return
            self.checked_info[cam] = intrinsics
        previous = self.info_stamp.get(cam)
        if previous is not None and stamp == previous:
            self.health.drop('stamp_not_newer', f'{cam}/camera_info repeats its previous stamp')
            return
        if previous is not None and stamp < previous:
            self._reset(
                f'{cam}/camera_info stamps went backwards (bag loop?): liveness and posteriors '
                'reset'
            )
        self.info_stamp[cam] = stamp
        self.liveness.seen(cam, stamp, 'camera_info')
        if self.last_frame_ns is not None and stamp <= self.last_frame_ns:
            if stamp < self.last_frame_ns:
                self.health.drop(
                    'stamp_not_newer', f'{cam}/camera_info for a frame older than the current one'
                )
            return  # equal: this frame is under way
        self.last_frame_ns = stamp
        if not self.schedule.keeps(stamp):
            count_shed(self.health, self.schedule, stamp, 'no assignment')
            return
        self._frame(stamp)

    def _reset(self, why: str) -> None:
        self.liveness.reset()
        self.posteriors.clear()
        self.info_stamp.clear()
        self.last_frame_ns = None
        self.schedule.clear()
        self.health.note('time_jump_resets', why)

    # ----------------------------------------------------------------- frame
    def _posterior(self, stamp: int) -> tuple[int, np.ndarray, np.ndarray] | None:
        """Return the newest posterior older than the frame, if recent enough to predict from."""
        for entry in reversed(self.posteriors):
            if entry[0] < stamp:
                age = (stamp - entry[0]) * 1e-9
                return entry if age <= self.params['max_posterior_age'] else None
        return None

    def _frame(self, stamp: int) -> None:
        self.health.count('frames_in')
        start = time.perf_counter()
        alive = self.liveness.alive(stamp)
        self._log_liveness(alive, stamp)
        posterior = self._posterior(stamp)
        try:
            if posterior is None:
                assignment = Assignment.all_cameras(list(self.names), alive, len(PART_NAMES))
                self.health.count('no_posterior')
            else:
                stamp_prev, q_prev, qdot_prev = posterior
                q_pred, _ = self.motion.predict_coordinates(
                    q_prev, qdot_prev, (stamp - stamp_prev) * 1e-9
                )
                # extrapolated hinges may pass their ranges; absurd rates fly the body away
                problem = pose_problem(self.body, q_pred, self.volume, limits=False)
                if problem:
                    self.health.note(
                        'absurd_prediction',
                        f'frame {stamp}: the predicted pose is absurd ({problem}): '
                        'every live camera assigned to every part',
                    )
                    assignment = Assignment.all_cameras(list(self.names), alive, len(PART_NAMES))
                else:
                    assignment = self.selector.assign(q_prev, q_pred, alive)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            self.health.drop('selection_failed', f'frame {stamp}: {exc}')
            return
        self.publisher.publish(assignment_to_message(assignment, stamp))
        elapsed = 1000.0 * (time.perf_counter() - start)
        self.frame_ms.append(elapsed)
        self.health.count('assignments_published')
        self.health.set('mode', assignment.mode)
        self.health.set('cameras_alive', ','.join(c for c in self.names if alive[c]) or 'none')
        self.health.set(
            'unobserved_parts',
            ','.join(p for p, o in zip(PART_NAMES, assignment.observed) if not o) or 'none',
        )
        self.health.set('last_frame_ms', f'{elapsed:.2f}')
        self.health.ok()
        self.get_logger().debug(
            f'frame {stamp * 1e-9:.6f} {assignment.mode}: {selection_line(assignment)}'
        )
        published = self.health.counters['assignments_published']
        if published % self.params['summary_every'] == 0:
            unobserved = [p for p, o in zip(PART_NAMES, assignment.observed) if not o]
            self.get_logger().info(
                f'{published} assignments; frame {stamp * 1e-9:.3f} {assignment.mode}, cameras '
                'alive '
                f'{",".join(c for c in self.names if alive[c]) or "none"}, unobserved '
                f'{",".join(unobserved) or "none"}; median {np.median(self.frame_ms):.2f} ms per '
                'frame'
            )

    def _log_liveness(self, alive: dict[str, bool], stamp: int) -> None:
        """Say when a camera times out or comes back."""
        for cam in self.names:
            if alive[cam] != self.was_alive[cam]:
                if alive[cam]:
                    self.get_logger().info(f'{cam} is back: assigned again')
                else:
                    self.health.note(
                        'camera_timeouts',
                        f'{cam}: no camera_info or contours for more than '
                        f'{self.settings.camera_timeout_s:g} s: excluded',
                    )
                self.was_alive[cam] = alive[cam]


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run memo_ros selector_node``."""
    return run_node('selector_node', SelectorNode, args)


if __name__ == '__main__':
    sys.exit(main())
