"""The graph benchmark's probe: restamped frames out, every output topic's arrival per frame in."""

from __future__ import annotations

from dataclasses import dataclass, field
import struct
import threading
import time

from memo_ros.ros.body_messages import processed_outcome

ASSIGNMENT_TOPIC = '/memo/camera_assignment'
JOINT_STATES_TOPIC = '/memo/joint_states'


PROCESSED_TOPIC = '/memo/processed'
CAMERA_INFO_WAIT_S = 0.2  # a camera_info waits this long for its frame's first image to go out


def header_stamp_ns(cdr: bytes) -> int:
    """Return the header stamp of a serialized message that starts with a std_msgs/Header."""
    endian = '<' if cdr[1] & 1 else '>'  # CDR encapsulation: 0x0001 little, 0x0000 big endian
    sec, nanosec = struct.unpack_from(endian + 'iI', cdr, 4)
    return sec * 1_000_000_000 + nanosec


def restamped(cdr: bytes, stamp_ns: int) -> bytes:
    """Return the serialized message with its header stamp replaced.

    The stamp follows the 4-byte encapsulation.
    """
    endian = '<' if cdr[1] & 1 else '>'
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return cdr[:4] + struct.pack(endian + 'iI', sec, nanosec) + cdr[12:]


@dataclass
class FrameTrace:
    """One frame as it went through the graph.

    Its stamp and the publication time (ns) of each output.
    """

    index: int  # frame of the bag, from 0
    stamp: int  # wall clock when its first message went out
    images_out: int | None = None  # wall clock when the last of its images went out
    contours: dict[str, int] = field(default_factory=dict)
    assignment: int | None = None
    joint_states: int | None = None
    processed: int | None = None
    outcome: str | None = None


class Restamper:
    """BagPlayer hook.

    Each frame (a bag stamp) gets the wall-clock time when its first image goes out.

    Both players (images and camera_info) call it from their own threads; a frame's later messages
    get the same stamp, so the frame keeps one stamp through the whole graph. A camera_info waits
    (up to CAMERA_INFO_WAIT_S) for its frame's first image, as a camera driver sends them
    together: the images of three cameras from one Python thread fall behind the small
    camera_info messages of the other (by 200 ms after 15 s at 60 Hz, measured), and a frame
    stamped by its camera_info would count that lag of the player as the graph's latency.
    """

    def __init__(self, on_frame=None) -> None:
        self.on_frame = on_frame
        self.frames: dict[int, FrameTrace] = {}  # new stamp -> trace
        self.messages: dict[str, int] = {}  # topic -> messages published
        self._stamps: dict[
            tuple[int, int], int
        ] = {}  # (pass through the bag, bag stamp) -> new stamp
        self._lock = threading.Lock()
        self._stamped = threading.Condition(self._lock)
        self._newest = 0
        self._player = threading.local()  # each player thread counts its own passes

    def before_publish(self, item) -> None:
        """Restamp a frame's messages to the wall clock as they go out."""
        original = header_stamp_ns(item.data)
        player = self._player
        if original < getattr(player, 'last', original):  # the bag starts again (--loops)
            player.passes = getattr(player, 'passes', 0) + 1
        player.last = original
        key = (getattr(player, 'passes', 0), original)
        image = item.topic.endswith('/image_raw')
        with self._stamped:
            if not image:
                self._stamped.wait_for(lambda: key in self._stamps, CAMERA_INFO_WAIT_S)
            stamp = self._stamps.get(key)
            if stamp is None:
                stamp = self._stamps[key] = max(time.time_ns(), self._newest + 1)
                self._newest = stamp
                trace = self.frames[stamp] = FrameTrace(len(self.frames), stamp)
                self._stamped.notify_all()
                if self.on_frame is not None:
                    self.on_frame(trace)
            self.messages[item.topic] = self.messages.get(item.topic, 0) + 1
            if image:
                self.frames[stamp].images_out = time.time_ns()
        item.data = restamped(item.data, stamp)


class Probe:
    """Subscribes the graph's outputs and files each message's publication time under its frame."""

    def __init__(
        self, node, cameras: list[str], frames: dict[int, FrameTrace], on_processed=None
    ) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState, PointCloud2
        from std_msgs.msg import Header

        from memo_ros.ros.dds import qos_profile

        self.frames = frames
        self.on_processed = on_processed
        self.unknown = 0  # outputs whose stamp is no published frame's
        self.last_output = time.monotonic()
        self.diagnostics: dict[str, dict] = {}  # node label -> {'values': ..., 'time': monotonic}
        self.frame_ms: dict[
            str, list[tuple[float, float]]
        ] = {}  # node label -> (monotonic, last_frame_ms)
        reliable = qos_profile('reliable', 1000)
        self.topics = [f'/{c}/contours' for c in cameras] + [
            ASSIGNMENT_TOPIC,
            JOINT_STATES_TOPIC,
            PROCESSED_TOPIC,
        ]
        for cam in cameras:
            node.create_subscription(
                PointCloud2,
                f'/{cam}/contours',
                lambda data, info, cam=cam: self._on_contours(cam, data, info),
                reliable,
                raw=True,
            )
        node.create_subscription(
            DiagnosticArray, ASSIGNMENT_TOPIC, self._on_assignment, reliable, raw=True
        )
        node.create_subscription(
            JointState, JOINT_STATES_TOPIC, self._on_joint_states, reliable, raw=True
        )
        node.create_subscription(Header, PROCESSED_TOPIC, self._on_processed, reliable)
        node.create_subscription(
            DiagnosticArray, '/diagnostics', self._on_diagnostics, qos_profile('reliable', 100)
        )

    def _trace(self, stamp: int) -> FrameTrace | None:
        self.last_output = time.monotonic()
        trace = self.frames.get(stamp)
        if trace is None:
            self.unknown += 1
        return trace

    def _on_contours(self, cam: str, data: bytes, info: dict) -> None:
        if (trace := self._trace(header_stamp_ns(data))) is not None:
            trace.contours.setdefault(cam, published_ns(info))

    def _on_assignment(self, data: bytes, info: dict) -> None:
        if (trace := self._trace(header_stamp_ns(data))) is not None and trace.assignment is None:
            trace.assignment = published_ns(info)

    def _on_joint_states(self, data: bytes, info: dict) -> None:
        if (
            trace := self._trace(header_stamp_ns(data))
        ) is not None and trace.joint_states is None:
            trace.joint_states = published_ns(info)

    def _on_processed(self, msg, info: dict) -> None:
        trace = self._trace(msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec)
        if trace is not None and trace.processed is None:
            trace.processed, trace.outcome = published_ns(info), processed_outcome(msg.frame_id)
            if self.on_processed is not None:
                self.on_processed(trace)

    def _on_diagnostics(self, msg) -> None:
        now = time.monotonic()
        for status in msg.status:
            label = status.name.strip('/')
            values = {kv.key: kv.value for kv in status.values}
            self.diagnostics[label] = {'values': values, 'time': now}
            if 'last_frame_ms' in values:
                self.frame_ms.setdefault(label, []).append((now, float(values['last_frame_ms'])))


def published_ns(info: dict) -> int:
    """When the publisher wrote the message: its DDS source timestamp (system clock, ns)."""
    return int(info.get('source_timestamp') or info.get('received_timestamp') or time.time_ns())
