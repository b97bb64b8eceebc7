"""contour_node: one camera's person segmentation, occluding contours and edge lines.

Subscribes ``image_raw`` and ``camera_info`` in its namespace and publishes,
for every accepted frame (header copied from the image): ``contours``
(PointCloud2: x, y, tx, ty, contour), ``person_box`` (PolygonStamped: the
enclosing rectangle's four corners in pixels, empty when nobody is seen),
``edges`` (PointCloud2: x1, y1, x2, y2, magnitude, chain) while someone
subscribes to it (the ``edges`` parameter: auto, always, never) and, on
request, ``debug/mask`` (mono8).  The science is memo_ros.core's ContourPipeline.

With ``keep_regions: tracked`` or the ``sequence`` segmenter it also listens to
the tracker's ``/memo/markers``: the tracked body projected into this camera
(the studio's calibration of the camera named like the namespace) and grown by
``roi_margin`` tells which regions are the person and where the background may
be learnt.  ``background_bag`` lets the sequence segmenter learn the
background from a recording of the scene (the one being replayed, or a clip
taken before) at start-up instead of from the first live frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import sys
import time

from geometry_msgs.msg import Point32, PolygonStamped
import numpy as np
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from visualization_msgs.msg import MarkerArray

from memo_ros.core.formats.background_file import (
    BackgroundFileError,
    BackgroundRecord,
    load_background,
    save_background,
)
from memo_ros.core.latency.decimation import DecimationSchedule
from memo_ros.core.vision.background import BackgroundModel, background_from_frames
from memo_ros.core.vision.contours import ContourPipeline, PipelineSettings
from memo_ros.core.vision.encodings import ImageFormatError
from memo_ros.core.vision.tracked_region import body_region, tracked_person
from memo_ros.ros.body_messages import MARKERS_TOPIC, tracked_body_from_markers
from memo_ros.ros.decimation_messages import count_shed, follow_decimation
from memo_ros.ros.health import NodeHealth
from memo_ros.ros.images import image_message_to_frame, image_message_to_grey
from memo_ros.ros.lost_frames import LostFrameCounter
from memo_ros.ros.messages import stamp_to_ns
from memo_ros.ros.node_main import run_node
from memo_ros.ros.params import Param, declare
from memo_ros.ros.pointcloud import array_to_pointcloud

PARAMS = (
    Param(
        'segmenter',
        'background',
        'person segmentation: a static background learnt over the first frames, '
        "Rohr's change detection against the previous frame, or a background learnt from a "
        'sequence that '
        'never shows the scene empty (colour, person masked out, kept learning)',
        choices=('background', 'change', 'sequence'),
    ),
    Param(
        'threshold',
        4.0,
        "threshold T of Rohr eq. 1, grey levels, raised to the frame's noise floor "
        '(about 4 against a background, 12 against the previous frame)',
        0.5,
        255.0,
    ),
    Param(
        'background_frames',
        10,
        'frames the background segmenter learns from before it segments (sequence, '
        'with background_bag: at most this many, spread over the recording)',
        1,
        10000,
    ),
    Param(
        'background_bag',
        '',
        "sequence segmenter: a rosbag2 with this camera's image_raw of the same scene "
        '(the recording being replayed, or a clip taken before); the background is learnt from '
        'it at start-up instead of from the first live frames, its motion tests comparing the '
        'images nearest 55 ms apart by their stamps',
        read_only=True,
    ),
    Param(
        'background_track',
        '',
        "sequence segmenter with background_bag: the tracker's output bag of a first "
        'pass over that recording; its /memo/markers body, grown by background_track_margin, is '
        'never learnt '
        'from (where the person stands still in most frames the background would show him)',
        read_only=True,
    ),
    Param(
        'background_track_margin',
        4.0,
        "background_track: the tracked body's projection grown by this many pixels",
        0.0,
        200.0,
        read_only=True,
    ),
    Param(
        'learn_margin',
        6,
        'sequence segmenter: pixels around the person and the tracked body not learnt from',
        0,
        200,
    ),
    Param(
        'roi_margin',
        20.0,
        "tracked region: the tracked body's projection grown by this many pixels",
        0.0,
        500.0,
    ),
    Param(
        'roi_max_age',
        0.5,
        'tracked region: /memo/markers older than the image by more than this (stamp time) '
        'are not used, s',
        0.0,
        3600.0,
    ),
    Param(
        'roi_wait',
        0.0,
        "tracked region: longest wait for the tracker's body of the previous image before an "
        'image is segmented, s (0: segment at once with the newest body; bag replay waits so '
        'that the result '
        'does not depend on which message DDS delivers first)',
        0.0,
        10.0,
    ),
    Param(
        'background_file',
        '',
        'PNG where the learnt background is saved and, when it exists at start, loaded '
        'from instead of learning (a restarted node must not learn the person into it); empty: '
        'off',
        read_only=True,
    ),
    Param(
        'background_max_moved',
        200,
        'background_file: a background in whose learning frames this many pixels moved (a '
        'person in view) is used but not saved, and such a file is refused at load, pixels',
        1,
        10_000_000,
        read_only=True,
    ),
    Param(
        'cleanup_delete_below',
        3,
        'cleanup: a flagged pixel with fewer flagged 3x3 neighbours is deleted',
        0,
        8,
    ),
    Param(
        'cleanup_fill_above',
        5,
        'cleanup: an unflagged pixel with more flagged 3x3 neighbours is marked',
        0,
        8,
    ),
    Param('cleanup_max_iterations', 10, 'cleanup: repetitions until stable (upper bound)', 1, 100),
    Param('min_region_area', 200, 'smallest kept region, pixels', 1, 10_000_000),
    Param(
        'window_margin',
        32,
        "background segmenter: segment only the box around the previous frame's person (and "
        'the tracked region) grown by this many pixels; the whole frame every '
        'full_frame_every frames, while the background is learnt, and again at once when the '
        "person reaches the box's edge (a live latency measure); 0 segments every whole frame "
        '(memo-ros launch --reliable-images, and so memo-ros replay, set 0)',
        0,
        100_000,
    ),
    Param(
        'full_frame_every',
        15,
        'window_margin: every this many frames the whole frame is segmented (a person who '
        'enters the view, or a second one, is found within that many frames)',
        1,
        1_000_000,
    ),
    Param(
        'keep_regions',
        'all',
        'keep the largest region, all regions above the minimum area, or those '
        "overlapping the tracked body (else the previous frame's person, else the largest)",
        choices=('largest', 'all', 'tracked'),
    ),
    Param('contour_step', 2.0, 'arc-length step between contour samples, pixels', 0.5, 50.0),
    Param(
        'smoothing',
        2.0,
        'smoothing of the closed contour: Gaussian low-pass sigma along the arc, pixels',
        0.0,
        50.0,
    ),
    Param(
        'edges',
        'auto',
        "Rohr's edge lines on edges (only the walker reads them): auto computes and publishes "
        'them only while edges has a subscriber, asked before and after each frame is processed '
        '(one that matched late gets them with every frame published from then on), always for '
        'every frame, never (edges stays silent)',
        choices=('auto', 'always', 'never'),
    ),
    Param(
        'edge_low',
        30.0,
        'edge detector: low hysteresis threshold (gradient magnitude)',
        0.0,
        2000.0,
    ),
    Param(
        'edge_high',
        80.0,
        'edge detector: high hysteresis threshold (gradient magnitude)',
        0.0,
        2000.0,
    ),
    Param('min_edge_length', 6.0, 'shortest edge line kept, pixels', 1.0, 1000.0),
    Param(
        'publish_debug_mask', False, 'also publish the cleaned person mask on debug/mask (mono8)'
    ),
    Param(
        'reliable_images',
        False,
        'subscribe images reliably (bag replay) instead of the sensor-data profile (best effort)',
        read_only=True,
    ),
    Param(
        'reliable_camera_info',
        True,
        'subscribe camera_info reliably; set false for a driver that publishes '
        'it best effort (a reliable subscription cannot match a best-effort publisher)',
        read_only=True,
    ),
    Param('image_queue_depth', 5, 'image subscription queue depth', 1, 1000, read_only=True),
    Param(
        'jump_back_frames',
        3,
        'images in a row stamped before the newest processed one that mean the clock jumped back '
        '(a bag loop): the frame history is reset; fewer are dropped as out of order',
        1,
        1000,
    ),
)
IMAGE_LOST_AFTER_S = 2.0  # wall time after its camera_info by which an image counts as lost
INFO_QUEUE_DEPTH = 100  # camera_info is small: a deep queue keeps every frame's announcement


@dataclass
class PendingImage:
    """An accepted image waiting (roi_wait) for the tracked body of the image before it."""

    msg: Image
    image: np.ndarray
    stamp: int
    previous_ns: int
    timer: object


def edges_wanted(mode: str, subscribers: int) -> bool:
    """Whether a frame's edge lines are computed and published.

    ``mode`` is the ``edges`` parameter, ``subscribers`` the edges publisher's matched
    subscriptions now.
    """
    if mode not in ('auto', 'always', 'never'):
        raise ValueError(f'edges={mode!r} is not one of auto, always, never')
    return subscribers > 0 if mode == 'auto' else mode == 'always'


def pipeline_settings(params: dict) -> PipelineSettings:
    """Return the core pipeline's settings from this node's parameters.

    Defaults for any not given.
    """
    p = {q.name: q.default for q in PARAMS} | dict(params)
    return PipelineSettings(
        segmenter=p['segmenter'],
        threshold=p['threshold'],
        background_frames=p['background_frames'],
        delete_below=p['cleanup_delete_below'],
        fill_above=p['cleanup_fill_above'],
        max_iterations=p['cleanup_max_iterations'],
        min_area=p['min_region_area'],
        window_margin=p['window_margin'],
        full_frame_every=p['full_frame_every'],
        keep=p['keep_regions'],
        learn_margin=p['learn_margin'],
        contour_step=p['contour_step'],
        smoothing=p['smoothing'],
        edge_low=p['edge_low'],
        edge_high=p['edge_high'],
        min_edge_length=p['min_edge_length'],
    )


def recording_background(
    frames: list[np.ndarray],
    stamps: list[int],
    camera,
    params: dict,
    bodies: dict[int, tuple] | None = None,
) -> BackgroundModel:
    """Return the sequence segmenter's background of a recording (background_bag).

    At most background_frames of ``frames``, without the ``bodies`` a first pass tracked at
    ``stamps`` (background_track) when given.
    """
    person_at = (
        None
        if bodies is None
        else tracked_person(
            camera, bodies, stamps, frames[0].shape[:2], params['background_track_margin']
        )
    )
    return background_from_frames(
        frames, params['background_frames'], params['threshold'], person_at, stamps
    )


class ContourNode(Node):
    """Per-camera segmentation and contour extraction."""

    def __init__(self, **kwargs) -> None:
        super().__init__('contour_node', **kwargs)
        self.params = declare(
            self,
            PARAMS,
            on_change=lambda: self.health.guard(self._on_parameters_set, 'parameter change')(),
        )
        camera = self.get_namespace().strip('/') or 'camera'
        self.health = NodeHealth(self, self.get_fully_qualified_name(), hardware_id=camera)
        self.camera_name = camera
        self.camera = self._studio_camera()
        self.background = self._learn_background_from_bag()
        self.pipeline = self._new_pipeline()
        self.camera_info: CameraInfo | None = None
        self.last_stamp_ns: int | None = None
        self.last_kept_ns: int | None = None  # the newest image not shed (roi_wait's previous)
        self.schedule = DecimationSchedule()  # the frames the graph keeps (the tracker's word)
        self.backward_stamps: list[int] = []  # the current run of images older than the newest
        self.markers: tuple[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = (
            None
        )
        self.pending: PendingImage | None = None
        self.lost = LostFrameCounter()
        self._saved_background = None
        self._load_background()
        # sensor-data profile (best effort) for live cameras, reliable for bag replay
        image_qos = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE
            if self.params['reliable_images']
            else ReliabilityPolicy.BEST_EFFORT,
            history=HistoryPolicy.KEEP_LAST,
            depth=self.params['image_queue_depth'],
        )
        self._image_callback = self.health.guard(self._on_image, 'image callback')
        self._image_sub = self.create_subscription(
            Image, 'image_raw', self._image_callback, image_qos
        )
        info_qos = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE
            if self.params['reliable_camera_info']
            else ReliabilityPolicy.BEST_EFFORT,
            history=HistoryPolicy.KEEP_LAST,
            depth=INFO_QUEUE_DEPTH,
        )
        self._info_sub = self.create_subscription(
            CameraInfo,
            'camera_info',
            self.health.guard(self._on_camera_info, 'camera_info callback'),
            info_qos,
        )
        self.pub_contours = self.create_publisher(PointCloud2, 'contours', 10)
        follow_decimation(self, self.schedule, self.health)
        # the last images of a burst have no newer image to show they were lost
        self.create_timer(
            IMAGE_LOST_AFTER_S / 2, self.health.guard(self._count_expired, 'lost image timer')
        )
        self.pub_edges = self.create_publisher(PointCloud2, 'edges', 10)
        self.pub_box = self.create_publisher(PolygonStamped, 'person_box', 10)
        self.pub_mask = self.create_publisher(Image, 'debug/mask', 2)
        if self.camera is not None:
            self.create_subscription(
                MarkerArray,
                MARKERS_TOPIC,
                self.health.guard(self._on_markers, 'markers callback'),
                10,
            )

    @property
    def colour(self) -> bool:
        """The sequence segmenter compares colour images; the others grey levels."""
        return self.params['segmenter'] == 'sequence'

    def _on_parameters_set(self) -> None:
        if pipeline_settings(self.params) == self.pipeline.settings:
            # edges, the debug mask, the tracked region's and the time-jump parameters are read at
            # every frame: switching them must not cost the learnt background
            return
        self.pipeline = self._new_pipeline()
        self._saved_background = None
        self._load_background()
        self.health.note('reconfigured', 'parameters changed: pipeline rebuilt')

    # ------------------------------------------------------------ sequence background and tracked
    # region
    def _studio_camera(self):
        """Return this camera's calibration from the studio parameters.

        When the tracked region is wanted.
        """
        if self.params['keep_regions'] != 'tracked' and self.params['segmenter'] != 'sequence':
            return None
        try:
            from memo_ros.ros.studio_params import studio_from_node

            return studio_from_node(self).camera(self.camera_name)
        except (KeyError, ValueError) as exc:
            self.get_logger().warning(
                f'no studio calibration for {self.camera_name} ({exc}): the tracked body '
                "is not used; regions follow the previous frame's person"
            )
            return None

    def _learn_background_from_bag(self):
        """Return the sequence segmenter's background learnt from background_bag.

        None without one.
        """
        path = self.params['background_bag']
        if not path or self.params['segmenter'] != 'sequence':
            return None
        from memo_ros.ros.bagio import read_messages, tracked_bodies

        topic = f'/{self.camera_name}/image_raw'
        messages = [m.message for m in read_messages(path, [topic])]
        if not messages:
            raise ValueError(f'background_bag {path} has no {topic} images')
        track = self.params['background_track']
        if track and self.camera is None:
            raise ValueError(
                f"background_track needs {self.camera_name}'s calibration in the studio"
            )
        frames = [image_message_to_frame(m) for m in messages]
        model = recording_background(
            frames,
            [stamp_to_ns(m.header.stamp) for m in messages],
            self.camera,
            self.params,
            tracked_bodies(track) if track else None,
        )
        self.get_logger().info(
            f'background learnt from {min(len(frames), self.params["background_frames"])} of '
            f'{len(frames)} images of {path}'
            + (f' without the body tracked in {track}' if track else '')
            + f': {int(model.unseen.sum())} pixels never seen, noise {model.noise:.1f}'
        )
        return model

    def _new_pipeline(self) -> ContourPipeline:
        """Return the pipeline for the current parameters.

        Starting from the bag-learnt background if any.
        """
        pipeline = ContourPipeline(pipeline_settings(self.params))
        if self.background is not None:
            pipeline.segmenter.method.set_model(self.background.copy())
        return pipeline

    def _on_markers(self, msg: MarkerArray) -> None:
        """Keep the newest tracked body (one cylinder per part) for the next images."""
        tracked = tracked_body_from_markers(msg)
        if tracked is not None and (self.markers is None or tracked[0] >= self.markers[0]):
            self.markers = tracked
            if self.pending is not None and tracked[0] >= self.pending.previous_ns:
                self._segment_pending()

    def _waits_for_markers(self, previous_ns: int | None) -> bool:
        """roi_wait.

        Whether an image must wait for the tracked body of the image before it (only once the
        tracker has sent a body: without a tracker running, images never wait).
        """
        return (
            self.params['roi_wait'] > 0
            and self.camera is not None
            and self.markers is not None
            and previous_ns is not None
            and self.markers[0] < previous_ns
        )

    def _segment_pending(self, reason: str | None = None, message: str = '') -> None:
        """Segment the image that waited for the tracked body.

        It came, or (``reason`` noted) the wait ran out or another image came first.
        """
        pending, self.pending = self.pending, None
        pending.timer.cancel()
        self.destroy_timer(pending.timer)
        if reason:
            self.health.note(reason, message)
        self._segment(pending.msg, pending.image, pending.stamp)

    def _tracked_region(self, stamp: int, shape: tuple[int, int]) -> np.ndarray | None:
        """Return the tracked body's projection grown by roi_margin.

        From markers at most roi_max_age older.
        """
        if self.camera is None or self.markers is None:
            return None
        marker_stamp, body = self.markers
        if not 0 <= stamp - marker_stamp <= self.params['roi_max_age'] * 1e9:
            return None
        return body_region(self.camera, *body, shape, self.params['roi_margin'])

    # ------------------------------------------------------------ learnt background on disk
    def _load_background(self) -> None:
        """Start from the saved background when there is one (the node was restarted mid-session).

        Only a background learnt from an empty scene is used: one with a person in it, or with no
        record of how it was learnt, is refused in one line and the node learns anew.
        """
        self._body_seen_while_learning = False
        path = self.params['background_file']
        if not path or not Path(path).is_file() or self.params['segmenter'] != 'background':
            return
        size = (self.camera.width, self.camera.height) if self.camera is not None else (None, None)
        try:
            background, record = load_background(path, *size)
        except BackgroundFileError as exc:
            self.health.warn('background_refused', f'background_file refused: {exc}; learning')
            return
        self.pipeline.set_background(background)
        self._saved_background = self.pipeline.background
        self.get_logger().info(
            f'background loaded from {path} ({record.width}x{record.height}, learnt from '
            f'{record.frames} frames of the empty scene)'
        )

    def _save_background(self) -> None:
        """Write the freshly learnt background, with its record, so a restart can load it.

        Not when a person was in view while it was learnt: it is used for this session only.
        """
        path, background = self.params['background_file'], self.pipeline.background
        self._saved_background = background
        if not path or background is None:
            return
        record = BackgroundRecord(
            camera=self.camera_name,
            width=int(background.shape[1]),
            height=int(background.shape[0]),
            frames=int(self.params['background_frames']),
            moved_pixels=self.pipeline.moved_while_learning,
            tracked_body_in_view=self._body_seen_while_learning,
            max_moved_pixels=int(self.params['background_max_moved']),
        )
        try:
            save_background(path, background, record)
        except BackgroundFileError as exc:
            self.health.warn('background_not_saved', f'learnt background {exc} (kept for now)')
            return
        except OSError as exc:
            self.health.note(
                'background_not_saved', f'could not save the background to {path}: {exc}'
            )
            return
        self.get_logger().info(f'background learnt from an empty scene and saved to {path}')

    # ------------------------------------------------------------ inputs
    def _on_camera_info(self, msg: CameraInfo) -> None:
        if self.camera_info is None:
            self.get_logger().info(
                f'camera_info received: {msg.width}x{msg.height}, {msg.distortion_model}'
            )
        self.camera_info = msg
        for _ in self.lost.announced(stamp_to_ns(msg.header.stamp)):
            self._count_lost()
        self._count_missing()

    def _count_lost(self, detail: str = '') -> None:
        self.health.drop(
            'image_lost',
            f'camera_info came but its image did not{detail} (lost in transport or '
            'overwritten in a full queue)',
        )

    def _count_missing(self) -> None:
        for _ in range(self.lost.missing()):
            self.health.drop(
                'frames_missing',
                'the stamps of this camera skipped frame periods: frames whose image and '
                'camera_info never came (lost in transport or overwritten in a full queue)',
            )

    def _take_camera_infos(self) -> None:
        """Take every camera_info waiting in its queue now.

        The single-threaded executor takes one message of each subscription per round, so behind
        images slower than their rate the camera_info queue would fill and overwrite its oldest
        announcements: a frame whose image was lost too would be counted nowhere.
        """
        for _ in range(INFO_QUEUE_DEPTH):
            msg = take_message(self._info_sub)
            if msg is None:
                return
            self._on_camera_info(msg)

    def _count_expired(self) -> None:
        """Count the announcements no image answered within IMAGE_LOST_AFTER_S as image_lost.

        The images already in the queue are taken first: one that waits there is not lost.
        """
        self._take_camera_infos()
        for _ in range(self.params['image_queue_depth']):
            msg = take_message(self._image_sub)
            if msg is None:
                break
            self._image_callback(msg)
        for _ in self.lost.expired(IMAGE_LOST_AFTER_S):
            self._count_lost(f' within {IMAGE_LOST_AFTER_S:g} s')

    def _backward_run(self, stamp: int) -> list[int]:
        """Return the run of images stamped before the newest processed one, ending with this one.

        Each must be newer than the one before it to make one new timeline.
        """
        run = self.backward_stamps
        return [*run, stamp] if run and stamp > run[-1] else [stamp]

    def _on_image(self, msg: Image) -> None:
        self._take_camera_infos()  # every announcement up to this image, before it is judged
        stamp = stamp_to_ns(msg.header.stamp)
        backward = self.last_stamp_ns is not None and stamp < self.last_stamp_ns
        run = self._backward_run(stamp) if backward else []
        jumped = len(run) >= self.params['jump_back_frames']
        if self.lost.counted_lost(stamp) and not jumped:
            # its frame is counted (image_lost) already: it came after a newer image, or more than
            # IMAGE_LOST_AFTER_S after its camera_info
            if backward:  # still one of a run that may be a jump back
                self.backward_stamps = run
            self.health.note('late_images', 'an image came after it was counted lost: ignored')
            return
        self.health.count('frames_in')
        if not backward and stamp != self.last_stamp_ns and not self.schedule.keeps(stamp):
            self._shed(stamp)
            return
        if (
            self.pending is not None
        ):  # another image: the waiting one goes first, with what there is
            self._segment_pending(
                'roi_wait_overtaken',
                "an image came before the tracker's body of the one "
                'waiting for it: segmented with an older body',
            )
        if self.camera_info is None:
            # contours are in pixels and need no intrinsics: go on (the size check waits for
            # camera_info)
            self.health.note(
                'no_camera_info', 'image before any camera_info: processed without the size check'
            )
        if backward:
            # one stale image must not cost the learnt background: only a run of them (a bag
            # loop, a clock set back) starts the history anew
            self.backward_stamps = run
            if not jumped:
                self.lost.arrived(stamp)
                self.health.drop(
                    'out_of_order', 'image stamped before the newest processed one: dropped'
                )
                return
            self.backward_stamps = []
            self.pipeline = self._new_pipeline()
            self.markers = None
            self.schedule.clear()
            self.last_kept_ns = None
            for _ in self.lost.reset():
                self._count_lost()
            self._saved_background = None
            self._load_background()
            self.health.warn(
                'time_jump_resets',
                f'{self.params["jump_back_frames"]} images in a row went back in time (bag loop '
                'or clock jump): frame history reset',
            )
        elif self.last_stamp_ns is not None and stamp == self.last_stamp_ns:
            self.health.drop('duplicate_stamp', 'image with the same stamp as the previous one')
            return
        try:
            image = image_message_to_frame(msg) if self.colour else image_message_to_grey(msg)
        except ImageFormatError as exc:
            self.lost.arrived(stamp)
            self.health.drop(exc.reason, f'bad image: {exc}')
            return
        info = self.camera_info
        if info is not None and (msg.width, msg.height) != (info.width, info.height):
            self.lost.arrived(stamp)
            self.health.drop(
                'size_mismatch',
                f'image {msg.width}x{msg.height} differs from camera_info '
                f'{info.width}x{info.height}',
            )
            return
        # taken into the frame history: the counter's clock is the node's
        for _ in self.lost.received(stamp):
            self._count_lost()
        self._count_missing()
        self.backward_stamps.clear()
        self.last_stamp_ns = stamp
        previous_ns, self.last_kept_ns = self.last_kept_ns, stamp
        if self._waits_for_markers(previous_ns):
            self.pending = PendingImage(
                msg,
                image,
                stamp,
                previous_ns,
                self.create_timer(
                    self.params['roi_wait'],
                    self.health.guard(
                        lambda: self._segment_pending(
                            'roi_wait_timeouts',
                            "the tracker's body of the previous image did not come within "
                            'roi_wait: segmented with an older one',
                        ),
                        'roi_wait timer',
                    ),
                ),
            )
            return
        self._segment(msg, image, stamp)

    def _shed(self, stamp: int) -> None:
        """Leave out an image the graph's decimation does not keep: counted, not segmented."""
        for _ in self.lost.received(stamp):
            self._count_lost()
        self._count_missing()
        self.backward_stamps.clear()
        self.last_stamp_ns = stamp
        count_shed(self.health, self.schedule, stamp, 'image not segmented')

    def _segment(self, msg: Image, image: np.ndarray, stamp: int) -> None:
        """Segment one accepted image within the tracked region and publish its contours."""
        roi = self._tracked_region(stamp, image.shape[:2])
        self.pipeline.set_roi(roi)
        if self.pipeline.background is None and roi is not None and roi.any():
            self._body_seen_while_learning = True  # this background is not of an empty scene
        # edge lines only for a listener (Rohr's walker, a recorder; the studio's tracker reads
        # none), asked at every frame: a subscriber discovered late gets them from then on
        mode = self.params['edges']
        with_edges = edges_wanted(mode, self.pub_edges.get_subscription_count())
        result = self.pipeline.process(image, edges=with_edges, stamp_ns=stamp)
        if not with_edges and edges_wanted(mode, self.pub_edges.get_subscription_count()):
            # matched while this frame was processed: its edge lines go out with it all the same
            start = time.perf_counter()
            result.edges = self.pipeline.edge_lines(image, result)
            result.timings['edges'] = time.perf_counter() - start
            with_edges = True
        if (
            self.pipeline.background is not None
            and self.pipeline.background is not self._saved_background
        ):
            self._save_background()
        self._publish(msg, result, with_edges)
        self.health.count('processed')
        if result.warming_up:
            self.health.count('warming_up')
        self.health.set('contour_points', len(result.contours))
        self.health.set(
            'edge_lines',
            len(result.edges)
            if with_edges
            else ('off (no subscriber)' if mode == 'auto' else f'off (edges: {mode})'),
        )
        self.health.set('last_frame_ms', f'{1000 * sum(result.timings.values()):.2f}')
        self.health.ok()

    def _publish(self, image: Image, result, with_edges: bool) -> None:
        self.pub_contours.publish(array_to_pointcloud(result.contours, image.header))
        if with_edges:  # an empty cloud would say "no edge lines found", not "none computed"
            self.pub_edges.publish(array_to_pointcloud(result.edges, image.header))
        if self.pub_box.get_subscription_count():  # Rohr's walker, a recorder
            box = PolygonStamped()
            box.header = image.header
            if result.box is not None:
                x, y, w, h = (float(v) for v in result.box)
                box.polygon.points = [
                    Point32(x=px, y=py, z=0.0)
                    for px, py in ((x, y), (x + w, y), (x + w, y + h), (x, y + h))
                ]
            self.pub_box.publish(box)
        if self.params['publish_debug_mask']:
            mask = Image()
            mask.header = image.header
            mask.height, mask.width = result.mask.shape
            mask.encoding = 'mono8'
            mask.step = mask.width
            mask.data = (result.mask.astype(np.uint8) * 255).tobytes()
            self.pub_mask.publish(mask)


def take_message(subscription):
    """Return the next message waiting in ``subscription``'s queue, or None.

    What the executor does before it runs the callback.
    """
    with subscription.handle:
        taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
    return None if taken is None else taken[0]


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run memo_ros contour_node``."""
    return run_node('contour_node', ContourNode, args)


if __name__ == '__main__':
    sys.exit(main())
