"""tracker_node: the articulated EKF over DDS (Kakadiaris & Metaxas §2-4).

Subscribes every camera's ``/<cam>/contours`` and ``/memo/camera_assignment``,
joins them by header stamp with a bounded wait, runs
:class:`memo_ros.core.multiview.tracking.ArticulatedTracker` and publishes
``/memo/joint_states``, ``/memo/body_poses``, ``/memo/markers``,
``/memo/root_pose`` and ``/diagnostics``, all stamped with the frame's stamp.
Services like robot_localization's: ``~/reset`` (std_srvs/Trigger) and the
``~/set_pose`` topic (sensor_msgs/JointState with named coordinates).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import sys
import threading
import time
import traceback

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
import numpy as np
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, JointState, PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from memo_ros.core.latency.decimation import Decimation, DecimationSchedule
from memo_ros.core.latency.governor import FrameLoad, GovernorSettings, LatencyGovernor
from memo_ros.core.multiview.anatomy import pose_problem, studio_volume
from memo_ros.core.multiview.body_estimation import (
    PERSON_HEIGHT_M,
    estimate_body,
    frame_silhouettes,
    height_problem,
    scaled_body,
)
from memo_ros.core.multiview.body_height import HEIGHT_STEPS, fit_height
from memo_ros.core.multiview.motion import (
    ProcessNoise,
    coordinates_from_names,
    named_values_problem,
)
from memo_ros.core.multiview.proportions import MEASURE_FRAMES
from memo_ros.core.multiview.tracking import (
    LOST,
    TRACKING,
    ArticulatedTracker,
    TrackerSettings,
)
from memo_ros.ros.assignment_messages import assignment_from_message
from memo_ros.ros.body_messages import (
    PROCESSED_TOPIC,
    joint_state_message,
    marker_array_message,
    pose_array_message,
    processed_message,
    root_pose_message,
)
from memo_ros.ros.decimation_messages import (
    DECIMATION_QOS,
    DECIMATION_TOPIC,
    decimation_message,
)
from memo_ros.ros.health import INTERNAL_ERROR, NodeHealth
from memo_ros.ros.messages import stamp_to_ns
from memo_ros.ros.node_main import run_node
from memo_ros.ros.params import Param, declare
from memo_ros.ros.pointcloud import contour_cloud_to_table
from memo_ros.ros.studio_params import studio_from_node

PARAMS: tuple[Param, ...] = (
    Param('sigma_px', 1.0, 'image force noise across the contour (eq. 14), pixels', 0.05, 100.0),
    Param(
        'sigma_rim_px',
        3.0,
        "image force noise at a part's ends, where contour smoothing rounds tips, pixels",
        0.05,
        100.0,
    ),
    Param(
        'robust_scale',
        0.0,
        'Cauchy scale of the image forces in units of their noise: a force whose residual is r '
        'weighs 1 / (1 + (r / (robust_scale sigma))^2) of its plain weight, so contour the pose '
        'cannot explain (a segmentation fault) stops dragging it; 0 (default) is plain least '
        'squares, the paper: 1 halved the studio errors but changed the Pose2Sim demo for the '
        'worse',
        0.0,
        100.0,
    ),
    Param(
        'sigma_normal',
        0.0,
        'normal force noise (eq. 15), unit-vector units; 0 (default) switches the normal '
        'force off: k_z from pixel-staircase tangents is biased',
        0.0,
        10.0,
    ),
    Param(
        'search_px',
        25.0,
        'largest image distance between a contour sample and its model node, pixels',
        1.0,
        500.0,
    ),
    Param(
        'gate_sigma',
        4.0,
        'Mahalanobis gate on each measurement innovation, standard deviations',
        1.0,
        100.0,
    ),
    Param('iterations', 2, 'iterated-EKF relinearisations per frame', 1, 20),
    Param(
        'outline_probe_px',
        2.0,
        'a model node is on the predicted outline when a ray this far outside it misses '
        'the body, pixels',
        0.1,
        50.0,
    ),
    Param(
        'contour_smoothing',
        2.0,
        "contour_node's smoothing, pixels: samples it moved (tight curves) count less",
        0.0,
        50.0,
    ),
    Param(
        'limit_sigma',
        0.02,
        'joint ranges as soft pseudo-measurements, rad; 0 switches the limits off',
        0.0,
        10.0,
    ),
    Param(
        'hip_twist_sigma',
        0.1,
        "each hip's twist about the thigh's axis measured as 0 with this noise, rad: it ties the "
        "pelvis's heading to the legs (an elliptic torso hardly shows its own); a twist the feet "
        'show still wins; 0: off',
        0.0,
        10.0,
    ),
    Param(
        'process_noise_translation',
        2.0,
        'white-noise acceleration of the root position, m/s^2/sqrt(Hz)',
        0.001,
        100.0,
    ),
    Param(
        'process_noise_root_rotation',
        3.0,
        'white-noise angular acceleration of the root, rad/s^2/sqrt(Hz)',
        0.001,
        1000.0,
    ),
    Param(
        'process_noise_joint',
        6.0,
        'white-noise acceleration of every joint angle, rad/s^2/sqrt(Hz)',
        0.001,
        1000.0,
    ),
    Param(
        'nis_limit',
        30.0,
        'mean normalised innovation squared above which a frame is inconsistent',
        1.0,
        1e6,
    ),
    Param(
        'min_matched_fraction',
        0.3,
        'fewer contour samples used than this fraction makes a frame inconsistent',
        0.0,
        1.0,
    ),
    Param(
        'lost_after',
        5,
        'inconsistent or empty frames in a row before tracking is declared lost',
        1,
        1000,
    ),
    Param(
        'join_timeout',
        0.15,
        'longest wait for the rest of a frame (cameras, assignment) after its first message, s',
        0.001,
        10.0,
    ),
    Param(
        'camera_timeout',
        0.5,
        'a camera whose newest contours are older than this (stamp time) is not waited for, s',
        0.01,
        60.0,
    ),
    Param(
        'time_jump',
        1.0,
        'a stamp this far behind the last processed frame resets the filter (bag loop), s',
        0.01,
        3600.0,
    ),
    Param(
        'use_initial_pose',
        True,
        "start from the studio's initial_pose when it has one (else from the silhouettes)",
    ),
    Param(
        'wait_for_assignment',
        True,
        "wait (up to join_timeout) for the selector's assignment of each frame",
    ),
    Param(
        'body_source',
        'studio',
        "the body's dimensions: the studio file's, or the studio body's proportions "
        "scaled to the subject's height measured from the visual hull of the first frames' "
        'silhouettes (real recordings; memo-ros import writes the shipped average adult, its '
        'shoulder joints 380 mm apart)',
        choices=('studio', 'silhouettes'),
        read_only=True,
    ),
    Param(
        'body_frames',
        1,
        'body_source silhouettes: frames whose silhouettes measure the height (the ones before '
        'the last are reported waiting)',
        1,
        1000,
        read_only=True,
    ),
    Param(
        'body_height_min',
        PERSON_HEIGHT_M[0],
        'body_source silhouettes: the least standing height the silhouettes may give, m; a '
        'smaller body is not started (implausible_body: not one whole person in view) and the '
        'next frames measure again',
        0.3,
        3.0,
        read_only=True,
    ),
    Param(
        'body_height_max',
        PERSON_HEIGHT_M[1],
        'body_source silhouettes: the greatest standing height the silhouettes may give, m; '
        'a taller body is not started, as below body_height_min',
        0.3,
        3.0,
        read_only=True,
    ),
    Param(
        'body_height_fit',
        True,
        'body_source silhouettes: the height is the one at which the start fits the last of '
        "those frames best (contour misfit and silhouettes' disagreement), refitted from the "
        "visual hull's height up to 1.32 times it (a person in a lunge or a kick at the first "
        "frame; about 1 s more); false: the hull's",
        read_only=True,
    ),
    Param(
        'body_proportion_frames',
        MEASURE_FRAMES,
        'body_source silhouettes: tracked frames after the start over which the shoulder '
        "joints' width, then the upper arms' length, are each measured: every 3rd, the pose is "
        "refined with the size at 0.88 - 1.12 of the template's (about 5 frames' work, "
        'deferred like a search while behind) and scored by how much the silhouettes disagree, '
        "and the least of a parabola through the summed scores replaces the template's size "
        "when 2 % below it (a person whose shoulders or arms differ from the template's "
        "more than the height says); 0: the template's proportions",
        0,
        1000,
        read_only=True,
    ),
    Param(
        'max_contour_points',
        50000,
        'largest contour cloud taken from one camera (points); a larger one is refused before it '
        'is read (a 640x480 person has about 1,000)',
        10,
        10_000_000,
    ),
    Param(
        'samples_per_camera',
        TrackerSettings().samples_per_camera,
        'contour samples per camera in a tracked frame: every k-th of each contour, the least k '
        'that keeps within it (the noise per sample follows the spacing; a start takes all); '
        '400 cuts the update at 1,000 samples a camera by a third to a half but tracked the real '
        'Pose2Sim demo worse (docs/benchmarks.md); 0: all',
        0,
        1_000_000,
    ),
    Param(
        'hard_limits',
        True,
        'project every estimate into the anatomical joint ranges (knees flex backwards, elbows '
        'forwards); false leaves only the soft limit_sigma pull',
    ),
    Param(
        'twin_evidence',
        1.0,
        'evidence (robust contour misfit difference, sigma^2 per sample, with memory 0.9 per '
        'frame) that decides between the pose and its twin (turned 180 degrees, sides swapped); '
        '0 never follows the twin',
        0.0,
        100.0,
    ),
    Param(
        'legs_evidence',
        1.0,
        'evidence (as twin_evidence) that decides which leg is which: every start also follows '
        "the pose with its legs exchanged in place (each knee and ankle where the other leg's "
        "are), which a leg's silhouette cannot tell apart, until one labelling fits better by "
        'this much, both agree, the rival is behind after 3 frames, or 60 frames pass; 0 keeps '
        "the start's labelling",
        0.0,
        100.0,
    ),
    Param(
        'twin_silhouette',
        1.0,
        "evidence (sigma^2 per sample) per unit of the silhouettes' disagreement (pixels where "
        "the model's and the person's silhouettes differ, per person pixel, summed over the "
        'cameras) that the start and the twin contest add to the contour misfit: a person the '
        "model's cylinders fit less exactly can fit a turned pose's contours better while the "
        'silhouettes say otherwise (docs/benchmarks.md, a dancer not shaped like the model); 0: '
        'the contours alone',
        0.0,
        100.0,
    ),
    Param(
        'twin_recheck',
        30,
        'frames between two looks at the twin once decided, each refitting the twin from a '
        'broad prior (0: only at a start from the silhouettes and at inconsistent frames)',
        0,
        100000,
    ),
    Param(
        'travel_evidence',
        0.5,
        'twin evidence per frame (sigma^2 per sample) for the pose walking forwards, at twice '
        'travel_speed or faster; a decided pose walking backwards gets a look at its twin '
        '(0: the direction of travel is not used)',
        0.0,
        10.0,
    ),
    Param(
        'travel_speed',
        0.5,
        'm/s of the pelvis over 0.5 s at or below which the direction of travel says nothing '
        '(standing, dancing on the spot, a step aside)',
        0.05,
        5.0,
    ),
    Param(
        'limb_exchange',
        0.5,
        'rad a pair of limbs (legs, arms) changes its left-right difference by before it is tried '
        'exchanged, left for right; the exchange is kept when it fits the contours better, the '
        "silhouette's hold included (a fast kick seen from the side); 0 never tries",
        0.0,
        10.0,
    ),
    Param(
        'recover_margin',
        0.3,
        "misfit (sigma^2 per contour sample) above the track's running usual at which the pose, "
        'then the pose with each pair of limbs exchanged, are refitted from a broad prior until '
        'one is back within it, the best kept (a lost limb re-initialised; such a frame costs '
        'two to four usual ones); 0 never re-searches',
        0.0,
        100.0,
    ),
    Param(
        'pair_search',
        0.5,
        "when none of the search again's refits comes back within recover_margin, each pair of "
        'limbs is also posed together in the best canonical postures of each (a kick the filter '
        'followed with the standing leg), refined, refitted, and kept when it fits better by this '
        'misfit (sigma^2 per contour sample) than the pose and every other start (such a frame '
        'costs about ten usual ones); 0 never',
        0.0,
        100.0,
    ),
    Param(
        'limb_search',
        0.1,
        'at a start (the studio initial_pose, a restart, the silhouettes), each limb is tried in '
        'a few canonical postures with the rest of the body kept, the best refined, and the '
        'posture kept when it fits better by this misfit (sigma^2 per contour sample): a tracker '
        "started while an arm is raised finds it; 0 keeps the start pose's limbs",
        0.0,
        10.0,
    ),
    Param(
        'limb_recheck',
        5,
        'frames between two searches of each limb while tracking (as at a start, each limb alone, '
        'the rest of the body held; the limbs fall due on consecutive frames, one a frame): a '
        'limb the filter lost (an arm swung up fast) is found again; 0 searches only at a start',
        0,
        1000,
    ),
    Param(
        'limb_recheck_gain',
        5.0,
        'how much better (px^2 per contour sample, the cheap outline score) a limb found again '
        'while tracking must fit the contours than the limb where the filter has it',
        0.0,
        1000.0,
    ),
    Param(
        'hold_sigma_px',
        2.0,
        "noise (px) of the silhouette's hold on a model outline node that projects outside a "
        "camera's silhouette (or its convex hull, hold_hull): the node is pulled back, so a limb "
        'whose contour a neighbour took cannot stay where nothing is seen; 0 switches it off',
        0.0,
        100.0,
    ),
    Param(
        'hold_hull',
        True,
        "the hold's region is each camera's convex hull of its contours (true): a part the "
        'segmentation missed inside the outline is not pulled; false holds to the silhouette '
        "itself, for exact silhouettes only (on the Pose2Sim demo's real ones it pulled the legs "
        '350-500 mm off)',
    ),
    Param(
        'max_lag',
        1.0,
        'the live latency policy: frames are tracked in order, but one older than the newest '
        'complete frame by more than this (stamp time) is skipped (counted skipped_behind, '
        'reported skipped on /memo/processed) and the filter predicts through it; 0 tracks only '
        'the newest, a large value every frame (memo-ros launch --reliable-images, and so '
        'memo-ros replay, set 3600 s); below 1 s a tracker behind its cameras stays less late '
        'but skips more and may lose the track (measured in docs/nodes.md, latency policy)',
        0.0,
        3600.0,
    ),
    Param(
        'iterations_behind',
        1,
        'the live latency policy for the update: while a newer frame has been heard of (its '
        'camera_info or contours came), a frame that follows the last tracked one (none skipped '
        'between: the motion is one frame period) is updated with this many relinearisations '
        'instead of iterations (counted tracked_behind), about 7 ms less per relinearisation '
        'left out on 3 cameras; memo-ros launch --reliable-images (and so memo-ros replay) sets '
        '20, so that a slow machine makes a replay slower, not different',
        1,
        20,
    ),
    Param(
        'defer_searches',
        True,
        'the live latency policy for the searches (a limb exchange try, the search again for '
        'lost limbs, a look at the twin; each costs several frames of work): one due while a '
        'newer frame has been heard of (its camera_info or contours came) is put off to a frame '
        'with none newer (counted searches_deferred); false runs each when due (memo-ros launch '
        '--reliable-images, and so memo-ros replay, sets false)',
    ),
    Param(
        'reacquire_gap',
        0.25,
        'a frame this long after the last tracked one (stamp time: the tracker skipped frames '
        'behind a slow start or a search) starts from the last pose moved on the floor as far '
        "as the silhouettes' centre moved, when that fits its contours better than the "
        'constant-velocity prediction, and is updated with 5 relinearisations (counted '
        'reacquisitions); 0 keeps the prediction and the usual iterations, s',
        0.0,
        3600.0,
    ),
    Param(
        'latency_target',
        0.08,
        'the live latency policy for the whole graph: while the last 5 frames were each later '
        'than this (from the first message of the frame to tracked) and each queued (a newer '
        "frame's contours waited meanwhile, or a camera's contours were missing: a contour node "
        'behind loses images), the tracker announces on /memo/decimation that every node keeps '
        'one frame in 2, 3, ... (down to min_kept_rate), the same frames in every node, others '
        'counted shed; after 3 s with nothing queued, if the tracker would stay under 70 % busy, '
        'one more frame in each run is kept again. 0 processes every frame (memo-ros launch '
        '--reliable-images, and so memo-ros replay, sets 0), s',
        0.0,
        10.0,
    ),
    Param(
        'min_kept_rate',
        20.0,
        'the live latency policy: the graph never keeps fewer frames a second than this under '
        'overload (the motion between two kept frames grows with the decimation: at 60 Hz one in '
        '3 at most, at 30 Hz none), Hz',
        0.1,
        1000.0,
    ),
)
SET_POSE_TTL_S = 2.0  # wall time an accepted set_pose waits for the frame that starts from it
ANNOUNCED_WAIT_S = 2.0  # how long a frame only camera_info announced waits (contour_node's loss)
INFO_QUEUE_DEPTH = 100  # camera_info is small: a deep queue keeps every frame's announcement
# every frame's outcome is kept for a slow reader: a start from the silhouettes takes seconds live,
# and the frames it left behind are then reported skipped in one burst (240 at 30 Hz measured)
PROCESSED_DEPTH = 2000
LATE_STAMPS_KEPT = 512  # stamps of late frames remembered, so each is counted once
EXPIRY_CHECK_S = 0.02  # how often frames whose join wait expired are looked for
MISSES_BEFORE_NOT_WAITING = (
    3  # a camera missing from this many joined frames in a row is not waited for
)


@dataclass
class PendingFrame:
    """Messages of one stamp gathered so far.

    ``first_wall`` is when its first contours or assignment came (None while only camera_info
    announced it), ``announced_wall`` when the frame was first heard of.
    """

    first_wall: float | None
    announced_wall: float
    contours: dict[str, np.ndarray] = field(default_factory=dict)
    assignment: object | None = None


def tracker_settings(p: dict) -> TrackerSettings:
    """TrackerSettings from the node's parameter values."""
    return TrackerSettings(
        sigma_px=p['sigma_px'],
        sigma_rim_px=p['sigma_rim_px'],
        robust_scale=p['robust_scale'],
        sigma_normal=p['sigma_normal'],
        search_px=p['search_px'],
        gate_sigma=p['gate_sigma'],
        iterations=p['iterations'],
        outline_probe_px=p['outline_probe_px'],
        contour_smoothing=p['contour_smoothing'],
        limit_sigma=p['limit_sigma'],
        hip_twist_sigma=p['hip_twist_sigma'],
        nis_limit=p['nis_limit'],
        min_matched_fraction=p['min_matched_fraction'],
        lost_after=p['lost_after'],
        hard_limits=p['hard_limits'],
        twin_evidence=p['twin_evidence'],
        twin_silhouette=p['twin_silhouette'],
        twin_recheck=p['twin_recheck'],
        legs_evidence=p['legs_evidence'],
        travel_evidence=p['travel_evidence'],
        travel_speed=p['travel_speed'],
        limb_exchange=p['limb_exchange'],
        recover_margin=p['recover_margin'],
        pair_search=p['pair_search'],
        limb_search=p['limb_search'],
        limb_recheck=p['limb_recheck'],
        limb_recheck_gain=p['limb_recheck_gain'],
        hold_sigma_px=p['hold_sigma_px'],
        hold_hull=p['hold_hull'],
        reacquire_gap=p['reacquire_gap'],
        samples_per_camera=p['samples_per_camera'],
        process_noise=ProcessNoise(
            p['process_noise_translation'],
            p['process_noise_root_rotation'],
            p['process_noise_joint'],
        ),
    )


def governor_settings(p: dict) -> GovernorSettings:
    """GovernorSettings from the node's parameter values."""
    return GovernorSettings(latency_target_s=p['latency_target'], min_rate_hz=p['min_kept_rate'])


class TrackerNode(Node):
    """Joins contours and assignments per frame and runs the articulated EKF.

    The executor (one thread) only takes messages, services and parameters; frames are tracked on a
    thread of their own, so the join always sees what has arrived and, when the update falls behind
    the cameras by more than max_lag, skips ahead instead of letting the DDS queues overflow.
    (rclpy's multi-threaded executor with a tracking callback group did the same, but left complete
    frames waiting 0.3 - 2 s for their turn: a paced replay ran at a fifth of its speed.)
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('tracker_node', **kwargs)
        self.params = declare(
            self,
            PARAMS,
            on_change=lambda: self.health.guard(self._on_parameters_set, 'parameter change')(),
        )
        if self.params['body_height_min'] >= self.params['body_height_max']:
            raise ValueError(
                f'body_height_min ({self.params["body_height_min"]}) must be below '
                f'body_height_max ({self.params["body_height_max"]})'
            )
        self.studio = studio_from_node(self)
        self.body = self.studio.body
        self.camera_names = self.studio.camera_names
        self.volume = studio_volume(self.studio.cameras)
        initial = None
        if self.studio.initial_pose and self.params['use_initial_pose']:
            initial = coordinates_from_names(
                self.body, list(self.studio.initial_pose), list(self.studio.initial_pose.values())
            )
            problem = pose_problem(self.body, initial, self.volume)
            if problem:
                initial = None
                self.get_logger().error(
                    f"the studio's initial_pose is refused: {problem}; "
                    'starting from the silhouettes instead'
                )
        self.tracker = ArticulatedTracker(
            self.body, self.studio.cameras, tracker_settings(self.params), initial
        )
        self.body_silhouettes: list | None = (
            [] if self.params['body_source'] == 'silhouettes' else None
        )
        self.proportions_reported = 0  # measured proportions reported (_report_proportions)
        self.health = NodeHealth(self, self.get_fully_qualified_name(), hardware_id='memo_tracker')
        # join state and commands, shared by the executor and the tracking thread (under self.lock)
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)
        self.commands: list = []  # tracker changes asked for by services and parameters, in order
        self.pending: dict[int, PendingFrame] = {}
        self.last_processed_ns: int | None = None
        self.first_stamp_ns: int | None = None
        self.idle_since = time.monotonic()
        self.gap_since_tracked = True  # a frame skipped or not tracked since the last tracked one
        self.newest_contours_ns: dict[str, int] = {}
        self.set_pose_wall: float | None = None  # when an accepted set_pose is waiting for a frame
        self.missed_assignments = 0  # joined frames in a row without the selector's assignment
        self.missed: dict[str, int] = dict.fromkeys(
            self.camera_names, 0
        )  # joined frames in a row without it
        self.late_stamps: dict[int, None] = {}  # insertion-ordered sets of recent stamps
        self.done_stamps: dict[int, None] = {}
        self.shed_stamps: dict[int, None] = {}
        self.started_track = False  # the frame being tracked (re)started the track
        # the live latency policy: the frames the whole graph keeps (latency_target)
        self.schedule = DecimationSchedule()
        self.governor = LatencyGovernor(governor_settings(self.params))
        # deep queues: a burst of frames (bag replay, a slow update) waits instead of being
        # overwritten
        reliable = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=100
        )
        for cam in self.camera_names:
            self.create_subscription(
                PointCloud2,
                f'/{cam}/contours',
                self.health.guard(self._contour_callback(cam), f'{cam}/contours callback'),
                reliable,
            )
        # camera_info announces every frame (as to the selector): a frame whose images were lost
        # in every contour_node still gets its outcome on /memo/processed
        announcements = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE,
            history=HistoryPolicy.KEEP_LAST,
            depth=INFO_QUEUE_DEPTH,
        )
        for cam in self.camera_names:
            self.create_subscription(
                CameraInfo,
                f'/{cam}/camera_info',
                self.health.guard(self._on_announcement, f'{cam}/camera_info callback'),
                announcements,
            )
        self.create_subscription(
            DiagnosticArray,
            '/memo/camera_assignment',
            self.health.guard(self._on_assignment, 'camera_assignment callback'),
            reliable,
        )
        # the tracker itself is touched only by the tracking thread: set_pose, reset and parameters
        # queue commands
        self.create_subscription(
            JointState,
            '~/set_pose',
            self.health.guard(self._on_set_pose, 'set_pose callback'),
            reliable,
        )
        self.pub_joints = self.create_publisher(JointState, '/memo/joint_states', 10)
        self.pub_poses = self.create_publisher(PoseArray, '/memo/body_poses', 10)
        self.pub_markers = self.create_publisher(MarkerArray, '/memo/markers', 10)
        self.pub_root = self.create_publisher(PoseWithCovarianceStamped, '/memo/root_pose', 10)
        self.pub_processed = self.create_publisher(Header, PROCESSED_TOPIC, PROCESSED_DEPTH)
        self.pub_decimation = self.create_publisher(Header, DECIMATION_TOPIC, DECIMATION_QOS)
        self.create_service(
            Trigger, '~/reset', self.health.guard(self._on_reset, 'reset service', service=True)
        )
        self.health.set('tracking_state', self.tracker.status)
        self.health.set('initial_pose', 'studio' if initial is not None else 'silhouettes')
        self.get_logger().info(
            f'tracking with cameras {", ".join(self.camera_names)}; '
            f'initial pose: {"studio" if initial is not None else "from the silhouettes"}'
        )
        # a frame is tracked as soon as the intake completes it (notified), or when its wait
        # expires
        self.woken = False
        self.stopping = False
        self.failure: BaseException | None = None
        self.worker = threading.Thread(target=self._work, name='tracking', daemon=True)
        self.worker.start()

    def destroy_node(self) -> None:
        """Stop the tracking thread (it finishes its frame) before the node's entities go."""
        with self.lock:
            self.stopping = True
            self.wake.notify()
        self.worker.join(timeout=10.0)
        super().destroy_node()

    def _command(self, change) -> None:
        """Have the tracking thread apply ``change`` (a callable) before its next frame."""
        with self.lock:
            self.commands.append(change)
            self._notify()

    def _notify(self) -> None:
        """Wake the tracking thread (call under the lock)."""
        self.woken = True
        self.wake.notify()

    # ------------------------------------------------------------ parameters and services
    def _on_parameters_set(self) -> None:
        settings = tracker_settings(self.params)
        self._command(lambda: self.tracker.apply_settings(settings))
        with self.lock:
            self.governor.settings = governor_settings(self.params)
        self.health.note('reconfigured', 'parameters changed: tracker settings updated')

    def _on_reset(self, request, response):
        with self.lock:
            self.pending.clear()
        self._command(lambda: self.tracker.reset())
        self.health.note('resets', 'reset requested: re-initialising on the next frame')
        response.success = True
        response.message = 'tracker reset; it re-initialises on the next frame with contours'
        return response

    def _on_set_pose(self, msg: JointState) -> None:
        names, positions = list(msg.name), list(msg.position)
        problem = named_values_problem(names, positions)
        if problem:
            self.health.drop('bad_set_pose', f'set_pose refused: {problem}')
            return
        self._command(lambda: self._set_pose(names, positions))

    def _set_pose(self, names: list[str], positions: list[float]) -> None:
        """Set the pose on the tracking thread: coordinates not named keep the estimate's values.

        Unknown names are refused as bad_set_pose, a pose no person in the studio can take
        (:func:`pose_problem`) as absurd_set_pose; the filter then stays as it was.
        """
        try:
            base = self.tracker.ekf.q if self.tracker.status == TRACKING else None
            q = coordinates_from_names(self.body, names, positions, base)
        except KeyError as exc:
            self.health.drop('bad_set_pose', f'set_pose refused: {exc}')
            return
        try:
            self.tracker.set_pose(q)
        except ValueError as exc:
            self.health.drop('absurd_set_pose', f'set_pose refused: {exc}')
            return
        self.set_pose_wall = time.monotonic()
        self.health.note('set_pose', 'pose set: the next frame starts from it')

    # ------------------------------------------------------------ inputs (executor thread)
    def _contour_callback(self, cam: str):
        def on_contours(msg: PointCloud2) -> None:
            self._on_contours(cam, msg)

        return on_contours

    def _frame_for(self, stamp: int, what: str, announced: bool = False) -> PendingFrame | None:
        """Return the pending frame of ``stamp`` (call under the lock).

        None (counted) when it is late; a jump back in time resets the filter. ``announced``: the
        message is only a camera_info saying the frame exists, which starts no join wait.
        """
        if stamp in self.shed_stamps:
            self.health.count('shed_messages')
            return None
        last = self.last_processed_ns
        if last is not None and stamp <= last:
            if last - stamp > self.params['time_jump'] * 1e9:
                self.pending.clear()
                self.last_processed_ns = None
                self.first_stamp_ns = stamp
                self.newest_contours_ns.clear()
                self.done_stamps.clear()
                self.late_stamps.clear()
                self.shed_stamps.clear()
                if self.schedule.changes:  # a new timeline: every node keeps every frame again
                    self.schedule.clear()
                    self.governor = LatencyGovernor(governor_settings(self.params))
                    self._announce(Decimation())
                self.commands.append(lambda: self.tracker.reset())
                self.health.note(
                    'time_jump_resets', 'stamps jumped backwards (bag loop?): filter reset'
                )
            else:
                self._late(stamp, what)
                return None
        if self.first_stamp_ns is None:
            self.first_stamp_ns = stamp
        self.governor.heard(stamp)
        if not self.schedule.keeps(stamp):
            self._shed(stamp)
            return None
        now = time.monotonic()
        frame = self.pending.get(stamp)
        if frame is None:
            frame = self.pending[stamp] = PendingFrame(None if announced else now, now)
        elif frame.first_wall is None and not announced:
            frame.first_wall = now
        return frame

    def _on_announcement(self, msg: CameraInfo) -> None:
        """Note the frame a camera_info announces.

        Its images may all be lost before they become contours; it is then reported no_contours
        (or late, when newer frames were tracked already) instead of vanishing unaccounted.
        """
        stamp = stamp_to_ns(msg.header.stamp)
        with self.lock:
            if stamp in self.done_stamps or stamp in self.late_stamps or stamp in self.shed_stamps:
                return  # a frame already accounted for: its camera_info is no late message
            self._frame_for(stamp, 'camera_info', announced=True)

    def _late(self, stamp: int, what: str) -> None:
        """Return a message of a frame already processed or passed over.

        Counted; a frame first heard of now is accounted for once, on /memo/processed as 'late'.
        """
        if stamp in self.late_stamps or stamp in self.done_stamps:
            self.health.count('late_messages')
            return
        self.late_stamps[stamp] = None
        if len(self.late_stamps) > LATE_STAMPS_KEPT:
            del self.late_stamps[next(iter(self.late_stamps))]
        self.health.drop(
            'late_frame', f'{what} of a frame older than the last processed one arrived late'
        )
        self.pub_processed.publish(processed_message(stamp, 'late'))

    def _on_contours(self, cam: str, msg: PointCloud2) -> None:
        self.health.count(f'contours_in.{cam}')
        stamp = stamp_to_ns(msg.header.stamp)
        try:
            table = contour_cloud_to_table(msg, self.params['max_contour_points'])
        except ValueError as exc:
            self.health.drop('bad_contours', f'{cam}: contours unreadable: {exc}')
            return
        finite = (
            np.isfinite(table['x'])
            & np.isfinite(table['y'])
            & np.isfinite(table['tx'])
            & np.isfinite(table['ty'])
        )
        if not finite.all():
            self.health.count('nan_contour_points', int((~finite).sum()))
            self.health.drop(
                'nan_contour_points',
                f'{cam}: {int((~finite).sum())} contour points with NaN ignored',
            )
            table = table[finite]
        with self.lock:
            frame = self._frame_for(stamp, f'{cam} contours')
            # the camera is alive even when its contours come too late for their frame (after the
            # selector's assignment): it is waited for again, or it would never be
            self.newest_contours_ns[cam] = max(stamp, self.newest_contours_ns.get(cam, stamp))
            self.missed[cam] = 0
            if frame is None:
                return
            frame.contours[cam] = table
            self._notify()

    def _on_assignment(self, msg: DiagnosticArray) -> None:
        self.health.count('assignments_in')
        stamp = stamp_to_ns(msg.header.stamp)
        try:
            assignment = assignment_from_message(msg)
        except (ValueError, KeyError) as exc:
            self.health.drop('bad_assignment', f'camera assignment unreadable: {exc}')
            return
        unknown = [c for c in assignment.cameras if c not in self.camera_names]
        if unknown:
            self.health.drop(
                'assignment_unknown_camera',
                f'assignment names camera(s) not in the studio: {", ".join(unknown)} (ignored)',
            )
        with self.lock:
            frame = self._frame_for(stamp, 'assignment')
            if frame is not None:
                frame.assignment = assignment
                self._notify()

    # ------------------------------------------------------------ joining (under the lock)
    def _expected_cameras(self, stamp: int, frame: PendingFrame) -> list[str]:
        """Cameras worth waiting for.

        Alive in the assignment, or with recent contours; not one that was missing from the last
        few joined frames (its contour_node died, before the selector says so).
        """
        if frame.assignment is not None:
            a = frame.assignment
            cams = [c for c, alive in zip(a.cameras, a.alive) if alive and c in self.camera_names]
        else:
            window = self.params['camera_timeout'] * 1e9
            first = self.first_stamp_ns if self.first_stamp_ns is not None else stamp
            # a camera not heard from yet is waited for during the first camera_timeout of the
            # stream
            cams = [
                c
                for c in self.camera_names
                if stamp - self.newest_contours_ns.get(c, first) <= window
            ]
        return [
            c for c in cams if self.missed[c] < MISSES_BEFORE_NOT_WAITING or c in frame.contours
        ]

    def _complete(self, stamp: int, frame: PendingFrame) -> bool:
        waiting = self.missed_assignments < MISSES_BEFORE_NOT_WAITING
        if self.params['wait_for_assignment'] and waiting and frame.assignment is None:
            return False
        return all(c in frame.contours for c in self._expected_cameras(stamp, frame))

    def _next_frame(self) -> tuple[int, PendingFrame, list[str]] | None:
        """Return the frame to track now, with the expected cameras it lacks.

        The oldest complete one (older incomplete ones first, as they are), else the oldest whose
        wait exceeded join_timeout, going through with what arrived. Only time spent idle counts
        for the timeout: after a long update the queued messages get their turn. Frames more than
        max_lag older than the newest ready one are skipped.
        """
        ready = [s for s in sorted(self.pending) if self._complete(s, self.pending[s])]
        if not ready:
            now = time.monotonic()
            join = self.params['join_timeout']
            if now - self.idle_since < join:
                return None
            ready = sorted(
                s
                for s, f in self.pending.items()
                if (
                    now - f.first_wall > join
                    if f.first_wall is not None
                    else now - f.announced_wall > max(join, ANNOUNCED_WAIT_S)
                )
            )
            if not ready:
                return None
        horizon = ready[-1] - int(self.params['max_lag'] * 1e9)
        for old in [s for s in sorted(self.pending) if s < horizon]:
            del self.pending[old]
            self._skip(old)
        stamp = min(self.pending)  # in stamp order: an older, incomplete frame goes first as it is
        frame = self.pending.pop(stamp)
        self._done(stamp)  # from now on a message of this frame is late, not a new frame
        missing = [c for c in self._expected_cameras(stamp, frame) if c not in frame.contours]
        if frame.assignment is not None:
            if self.missed_assignments >= MISSES_BEFORE_NOT_WAITING:
                self.health.set('assignment', 'waited for')
            self.missed_assignments = 0
        elif self.params['wait_for_assignment']:
            self.missed_assignments += 1
            if self.missed_assignments == MISSES_BEFORE_NOT_WAITING:
                # a dead selector must not stall tracking: every visible camera updates every part
                self.health.note(
                    'assignment_not_waited_for',
                    f'no camera assignment in {MISSES_BEFORE_NOT_WAITING} frames in a row: not '
                    'waited for until one comes again; tracking with every camera',
                )
                self.health.set('assignment', 'missing (selector silent): every camera used')
        for cam in missing:
            self.missed[cam] += 1
            if self.missed[cam] == MISSES_BEFORE_NOT_WAITING:
                self.health.note(
                    'camera_not_waited_for',
                    f'{cam}: no contours in {MISSES_BEFORE_NOT_WAITING} frames '
                    'in a row: not waited for until they come again',
                )
        return stamp, frame, missing

    def _newer_frame_waits(self, stamp: int) -> bool:
        """Return whether a frame newer than ``stamp`` was heard of (the tracker is behind)."""
        with self.lock:
            return any(s > stamp for s in self.pending)

    def _skip(self, stamp: int) -> None:
        """Return a frame passed over because a newer one is ready.

        Counted, and reported done on /memo/processed.
        """
        self.health.drop(
            'skipped_behind',
            f'the tracker is more than max_lag = {self.params["max_lag"]:g} s '
            'behind: an older frame was skipped',
        )
        self._done(stamp)
        self.gap_since_tracked = True
        self.pub_processed.publish(processed_message(stamp, 'skipped'))

    def _shed(self, stamp: int) -> None:
        """Account for a frame the graph's decimation leaves out (call under the lock)."""
        self.shed_stamps[stamp] = None
        if len(self.shed_stamps) > LATE_STAMPS_KEPT:
            del self.shed_stamps[next(iter(self.shed_stamps))]
        every = self.schedule.at(stamp).every
        self.health.drop(
            'shed',
            f'the graph is over latency_target = {self.params["latency_target"]:g} s: it keeps '
            f'one frame in {every} (/memo/decimation)',
        )
        self.pub_processed.publish(processed_message(stamp, 'shed'))

    def _announce(self, decimation: Decimation) -> None:
        """Tell every node which frames to keep from ``decimation.from_ns`` on."""
        self.pub_decimation.publish(decimation_message(decimation))
        self.health.set('decimation', decimation.every)
        self.health.note(
            'decimation_changes',
            f'latency policy: one frame in {decimation.every} kept from stamp '
            f'{decimation.from_ns * 1e-9:.3f} on',
        )

    def _govern(
        self, stamp: int, frame: PendingFrame, missing: list[str], began: float, started: bool
    ) -> None:
        """Feed a processed frame's load to the governor and announce what it decides.

        It queued when a newer kept frame waited meanwhile, or when it lacked an expected
        camera's contours (a contour node behind loses images); the frame that (re)started the
        track does not count (a start is slow).
        """
        now = time.monotonic()
        with self.lock:
            if not started:
                waited = any(
                    s > stamp and f.first_wall is not None for s, f in self.pending.items()
                )
                queued = bool(missing) or waited
                load = FrameLoad(now - frame.announced_wall, now - began, queued)
                self.governor.processed(load, now)
            decimation = self.governor.decide(now)
            if decimation is not None:
                self.schedule.add(decimation)
                self._announce(decimation)

    def _done(self, stamp: int) -> None:
        self.last_processed_ns = (
            stamp if self.last_processed_ns is None else max(stamp, self.last_processed_ns)
        )
        self.done_stamps[stamp] = None
        if len(self.done_stamps) > LATE_STAMPS_KEPT:
            del self.done_stamps[next(iter(self.done_stamps))]

    # ------------------------------------------------------------ tracking (its own thread)
    def _work(self) -> None:
        """Run the tracking thread: woken by the intake, and every EXPIRY_CHECK_S for late joins.

        An error in a frame or a command is counted (internal_error) and the node goes on; one
        elsewhere ends the node (spin is shut down, the process exits 1), except while the node
        shuts down, when a publish into the invalidated context is expected and swallowed.
        """
        try:
            while True:
                with self.lock:
                    self.wake.wait_for(lambda: self.woken or self.stopping, EXPIRY_CHECK_S)
                    if self.stopping:
                        return
                    self.woken = False
                self._tick()
        except Exception as exc:  # noqa: BLE001 - reported, then the node stops
            if self._shutting_down():
                self.get_logger().debug(f'tracking thread stopped at shutdown: {exc!r}')
                return
            self.failure = exc
            self.get_logger().fatal(f'tracking thread failed: {exc!r}\n{traceback.format_exc()}')
            self.context.try_shutdown()

    def _tick(self) -> None:
        """Apply the queued commands, then track every frame that is ready, one after the other."""
        while True:
            with self.lock:
                commands, self.commands = self.commands, []
            for command in commands:
                try:
                    command()
                except Exception as exc:  # noqa: BLE001 - counted, the node goes on
                    if self._shutting_down():
                        raise
                    self.health.internal_error('a tracker command', exc)
            with self.lock:
                job = self._next_frame()
            if job is None:
                return
            stamp, frame, missing = job
            # on /diagnostics while a frame takes long (a start): a paced replay waits for it
            self.health.set('working_on', stamp)
            self.started_track = False
            began = time.monotonic()
            try:
                outcome = self._track(stamp, frame, missing)
            except Exception as exc:  # noqa: BLE001 - counted, the node goes on
                if self._shutting_down():
                    raise
                self.health.internal_error('tracking a frame', exc)
                self.tracker.reset(use_initial_pose=False)  # its state may be half updated
                outcome = INTERNAL_ERROR
            finally:
                self.health.set('working_on', '')
            self.gap_since_tracked = not outcome.startswith(TRACKING)
            self._govern(stamp, frame, missing, began, self.started_track)
            self.pub_processed.publish(processed_message(stamp, outcome))

    def _shutting_down(self) -> bool:
        """Whether the node is being destroyed or its context shut down (publishing may fail)."""
        return self.stopping or not self.context.ok()

    def _track(self, stamp: int, frame: PendingFrame, missing: list[str]) -> str:
        self.health.count('frames')
        # in the studio's camera order, not the order they came in: the fit sums over the cameras
        # in this order, and a start turns on the last bit of it (a replay gives the same track)
        frame.contours = {c: frame.contours[c] for c in self.camera_names if c in frame.contours}
        if missing:
            self.health.count('cameras_missing_in_frame', len(missing))
        if frame.assignment is None:
            self.health.count('frames_without_assignment')
        if not frame.contours:
            self.health.drop(
                'no_contours',
                'no camera contours came for a frame its camera_info or assignment announced '
                '(images lost or dropped in every contour_node)',
            )
            return 'no_contours'
        if self.tracker.status != TRACKING and missing:
            # a start is decided on one frame, and one from fewer views than the graph has settled
            # wrong (a restarted tracker whose first frame had one camera started turned round):
            # it waits for a frame with every expected camera; one missing from
            # MISSES_BEFORE_NOT_WAITING frames in a row is no longer expected
            self.health.drop(
                'start_incomplete',
                f'a start waits for a frame with every expected camera; missing: '
                f'{", ".join(missing)}',
            )
            return 'waiting'
        if self.body_silhouettes is not None and not self._measure_body(frame.contours):
            return 'waiting'
        if (
            self.set_pose_wall is not None
            and time.monotonic() - self.set_pose_wall > SET_POSE_TTL_S
            and self.tracker.status != TRACKING
        ):
            # a pose set for the next frame that no frame followed within the TTL is stale: it
            # must not decide how a later, unrelated stream starts
            self.tracker.reset()
            self.health.drop('set_pose_expired', 'set_pose not followed by a frame: discarded')
        self.set_pose_wall = None
        selected = None
        if frame.assignment is not None:
            selected = {
                c: mask for c, mask in frame.assignment.masks().items() if c in self.camera_names
            }
        may_search = (
            (lambda: not self._newer_frame_waits(stamp)) if self.params['defer_searches'] else None
        )
        iterations = None
        if (
            self.params['iterations_behind'] < self.params['iterations']
            and not self.gap_since_tracked  # after a gap the motion is larger: every iteration
            and self._newer_frame_waits(stamp)
        ):
            iterations = self.params['iterations_behind']
            self.health.count('tracked_behind')
        result = self.tracker.step(stamp, frame.contours, selected, may_search, iterations)
        self.idle_since = time.monotonic()
        self.health.set('tracking_state', result.status)
        self.health.set('cameras_in_frame', ','.join(sorted(frame.contours)))
        self.health.set('contour_samples', result.samples)
        self.health.set('samples_used', result.report.used)
        self.health.set('samples_gated', result.report.gated)
        self.health.set('samples_unselected', result.unselected)
        self.health.set('nis', f'{result.report.nis:.3f}')
        self.health.set('last_frame_ms', f'{1000 * result.seconds:.1f}')
        self.health.set('heading_confidence', f'{result.heading_confidence:.3f}')
        self.health.set('heading_undecided', str(result.undecided).lower())
        self.health.set('twin_swaps', result.twin_swaps)
        self.health.set('legs_undecided', str(result.legs_undecided).lower())
        self.health.set('leg_swaps', result.leg_swaps)
        self.health.set('limb_exchanges', result.limb_exchanges)
        self.health.set('recoveries', result.recoveries)
        self.health.set('limbs_found', result.limbs_found)
        self.health.set('searches_deferred', result.searches_deferred)
        self.health.set('reacquisitions', self.tracker.reacquisitions)
        self._report_proportions()
        if result.initialised:
            self.health.note('initialisations', 'track (re)initialised')
            self.started_track = True
            with self.lock:
                self.governor.restart()  # the backlog of a start says nothing about the load
        if result.status == LOST:
            self.health.drop(
                'tracking_lost',
                f'tracking lost: {result.reason}; re-initialising from the silhouettes',
            )
            return LOST
        if result.status != TRACKING:
            self.health.drop('no_body', f'no estimate: {result.reason}')
            return result.status
        self._publish(stamp, result)
        self.health.count('published')
        self.health.ok()
        outcome = TRACKING
        if result.undecided:
            self.health.count('published_undecided')
            outcome += f' heading_confidence={result.heading_confidence:.3f}'
        if result.legs_undecided:
            outcome += ' legs_undecided'
        return outcome

    def _report_proportions(self) -> None:
        """Once a proportion is measured (body_proportion_frames): publish and report it."""
        meters = self.tracker.proportions.done if self.tracker.proportions else []
        if len(meters) > self.proportions_reported:
            self.body = self.tracker.body  # the markers' body from the next frame on
        for meter in meters[self.proportions_reported :]:
            name = meter.proportion.name
            size = meter.proportion.size(meter.result)
            template = meter.proportion.size(meter.body)
            self.health.set(f'body_{name}_m', f'{size:.3f}')
            self.get_logger().info(
                f'{name.replace("_", " ")} measured over {meter.measured} frames: '
                f"{1e3 * size:.0f} mm (the template's {1e3 * template:.0f} mm; summed silhouette "
                'disagreement '
                + ', '.join(f'{1e3 * w:.0f} mm: {m:.2f}' for w, m in zip(meter.sizes, meter.sums))
                + ')'
            )
        self.proportions_reported = len(meters)

    def _implausible_body(self, why: str) -> None:
        """Count a frame whose silhouettes carve no person's height (body_height_min/max)."""
        self.health.drop(
            'implausible_body',
            f'body not started from the silhouettes: {why} (body_height_min, body_height_max): '
            'not one whole person in view; measuring again',
        )

    def _measure_body(self, contours: dict[str, np.ndarray]) -> bool:
        """body_source silhouettes.

        Gather the frame's silhouettes; once body_frames are in, scale the body to the measured
        height and start a tracker for it. True when the body is measured (track this frame).
        """
        self.body_silhouettes.append(frame_silhouettes(self.studio.cameras, contours))
        if len(self.body_silhouettes) < self.params['body_frames']:
            self.health.drop('measuring_body', 'frame used to measure the body, not tracked')
            return False
        frames, self.body_silhouettes = self.body_silhouettes, []
        try:
            body, height = estimate_body(frames, self.studio.body)
        except ValueError as exc:
            self.health.drop('measuring_body', f'body not measured: {exc}; trying again')
            return False
        hull, fit = height, None
        low, high = self.params['body_height_min'], self.params['body_height_max']
        fitted = self.params['body_height_fit']
        reach = HEIGHT_STEPS[-1] if fitted else 1.0  # the most the fit raises the hull's height
        if height_problem(hull, low / reach, high):
            self._implausible_body(
                f'their visual hull is {hull:.2f} m tall, and no standing height fitted from it '
                f'(up to {reach:.2f} times that) is within {low:.2f} - {high:.2f} m'
            )
            return False
        if fitted:
            fit = fit_height(
                self.studio.body,
                self.studio.cameras,
                contours,
                hull,
                tracker_settings(self.params),
            )
            body, height = scaled_body(self.studio.body, fit.height), fit.height
        problem = height_problem(height, low, high)
        if problem:
            self._implausible_body(f'they give a person {problem}')
            return False
        self.body = body
        # the studio's initial pose (use_initial_pose) holds for the measured body too; the
        # shoulders and the upper arms are measured while it tracks
        settings = replace(
            tracker_settings(self.params), proportion_frames=self.params['body_proportion_frames']
        )
        self.tracker = ArticulatedTracker(
            body, self.studio.cameras, settings, self.tracker.initial_pose
        )
        self.proportions_reported = 0
        self.body_silhouettes = None
        self.health.set('body_height_m', f'{height:.3f}')
        self.health.set('body_hull_height_m', f'{hull:.3f}')
        self.get_logger().info(
            f'body measured from {len(frames)} frame(s) of silhouettes: height {height:.3f} m '
            f'(visual hull {hull:.3f} m; the studio body, '
            f'{self.studio.body.standing_height():.3f} m, scaled)'
            + (
                '; starts fitted at '
                + ', '.join(f'{h:.3f} m: score {m:.3f}' for h, m in fit.tried)
                if fit is not None
                else ''
            )
        )
        return True

    def _publish(self, stamp: int, result) -> None:
        names = list(self.body.coordinate_names)
        self.pub_joints.publish(joint_state_message(stamp, names, result.q, result.qdot))
        # the other outputs are built only for a listener (the contour nodes' tracked region reads
        # the markers): a 14-part MarkerArray alone takes 0.5 ms to build in Python
        if self.pub_poses.get_subscription_count():
            self.pub_poses.publish(pose_array_message(stamp, result.rotations, result.origins))
        if self.pub_markers.get_subscription_count():
            self.pub_markers.publish(
                marker_array_message(stamp, self.body, result.rotations, result.origins)
            )
        if self.pub_root.get_subscription_count():
            # error-state order: root translation (x, y, z) then the root's rotation increment, as
            # REP 103 wants
            self.pub_root.publish(
                root_pose_message(
                    stamp, result.rotations[0], result.origins[0], result.covariance[:6, :6]
                )
            )


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run memo_ros tracker_node``."""
    return run_node('tracker_node', TrackerNode, args)


if __name__ == '__main__':
    sys.exit(main())
