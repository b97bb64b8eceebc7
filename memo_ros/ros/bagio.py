"""Writing and reading rosbag2 files without DDS (rosbags), in Jazzy's layout.

Bags are written from ``typestore.serialize_cdr`` (never from rclpy's
``serialize_message``, whose padding rosbags' strict decoder rejects) as mcap
with metadata version 9, like ``ros2 bag record`` on Jazzy.  Reading
deserializes with rclpy, which tolerates both, so any Jazzy bag reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from memo_ros.ros.messages import import_message_type, stamp_to_ns  # noqa: F401 - stamp_to_ns re-exported

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
STORAGE_PLUGINS = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
_T = TYPESTORE.types


def header(stamp_ns: int, frame_id: str):
    """Return a std_msgs/Header for the typestore."""
    return _T['std_msgs/msg/Header'](
        stamp=_T['builtin_interfaces/msg/Time'](
            sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
        ),
        frame_id=frame_id,
    )


def image_msg(stamp_ns: int, frame_id: str, pixels: np.ndarray, encoding: str):
    """sensor_msgs/Image from a (H, W) or (H, W, C) array."""
    pixels = np.ascontiguousarray(pixels)
    h, w = pixels.shape[:2]
    step = pixels.strides[0]
    return _T['sensor_msgs/msg/Image'](
        header=header(stamp_ns, frame_id),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=pixels.view(np.uint8).reshape(-1),
    )


def camera_info_msg(stamp_ns: int, fields: dict):
    """sensor_msgs/CameraInfo from :meth:`Camera.to_camera_info_fields`."""
    roi = _T['sensor_msgs/msg/RegionOfInterest'](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    return _T['sensor_msgs/msg/CameraInfo'](
        header=header(stamp_ns, fields['frame_id']),
        height=int(fields['height']),
        width=int(fields['width']),
        distortion_model=fields['distortion_model'],
        d=np.asarray(fields['d'], np.float64),
        k=np.asarray(fields['k'], np.float64),
        r=np.asarray(fields['r'], np.float64),
        p=np.asarray(fields['p'], np.float64),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def joint_state_msg(stamp_ns: int, names, positions, velocities=()):
    """sensor_msgs/JointState (frame ``world``)."""
    return _T['sensor_msgs/msg/JointState'](
        header=header(stamp_ns, 'world'),
        name=list(names),
        position=np.asarray(positions, np.float64),
        velocity=np.asarray(velocities, np.float64),
        effort=np.zeros(0, np.float64),
    )


def pose_array_msg(stamp_ns: int, positions: np.ndarray, quaternions_xyzw: np.ndarray):
    """geometry_msgs/PoseArray in ``world``, one pose per row."""
    point, quat, pose = (
        _T['geometry_msgs/msg/Point'],
        _T['geometry_msgs/msg/Quaternion'],
        _T['geometry_msgs/msg/Pose'],
    )
    poses = [
        pose(
            position=point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=quat(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        )
        for p, q in zip(positions, quaternions_xyzw)
    ]
    return _T['geometry_msgs/msg/PoseArray'](header=header(stamp_ns, 'world'), poses=poses)


class BagWriter:
    """A rosbag2 writer (mcap or sqlite3, metadata version 9) for typestore messages and raw bytes.

    :meth:`write` registers a topic on first use and serializes a typestore message;
    :meth:`add_connection` and :meth:`write_raw` store bytes received on the wire as they are.
    """

    def __init__(self, path: str | Path, storage: str = 'mcap') -> None:
        path = Path(path)
        if path.exists():
            raise FileExistsError(f'output bag {path} exists already')
        plugin = STORAGE_PLUGINS.get(storage)
        if plugin is None:
            raise ValueError(f'unknown storage {storage!r} (mcap or sqlite3)')
        self._writer = Writer(path, version=9, storage_plugin=plugin)
        self._writer.open()
        self._connections: dict[str, Connection] = {}
        self.path = path

    def write(self, topic: str, stamp_ns: int, message) -> None:
        """Serialize and append ``message`` on ``topic`` with log time ``stamp_ns``."""
        conn = self._connections.get(topic)
        if conn is None:
            conn = self.add_connection(topic, message.__msgtype__)
        self._writer.write(
            conn, stamp_ns, bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__))
        )

    def add_connection(
        self, topic: str, msgtype: str, offered_qos: list[Qos] | None = None
    ) -> Connection:
        """Register ``topic`` with its Jazzy message definition.

        And the QoS its publishers offered.
        """
        conn = self._writer.add_connection(
            topic, msgtype, typestore=TYPESTORE, offered_qos_profiles=offered_qos or []
        )
        self._connections[topic] = conn
        return conn

    def write_raw(self, connection: Connection, stamp_ns: int, data: bytes) -> None:
        """Append serialized bytes as received, with log time ``stamp_ns``."""
        self._writer.write(connection, stamp_ns, data)

    def close(self) -> None:
        """Finish the bag (metadata, mcap summary)."""
        self._writer.close()

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class BagMessage:
    """One deserialized message of a bag (an rclpy message object)."""

    topic: str
    msgtype: str
    log_time_ns: int
    message: object


class BagError(ValueError):
    """A bag that cannot be read, written or played as asked."""


def open_bag(path: str | Path) -> Reader:
    """Return an open rosbags Reader for a bag directory or a single .mcap/.db3 file.

    Or a BagError saying why not.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'no bag at {path}')
    if path.is_dir() and not (path / 'metadata.yaml').is_file():
        raise BagError(f'{path} is not a rosbag2 directory (no metadata.yaml)')
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises many unrelated types for unreadable bags
        raise BagError(f'cannot read bag {path}: {exc}') from None
    return reader


def read_messages(path: str | Path, topics: list[str] | None = None) -> Iterator[BagMessage]:
    """Deserialized messages of ``topics`` (all if None) in log-time order."""
    from rclpy.serialization import deserialize_message

    reader = open_bag(path)
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if not conns:  # rosbags reads every connection when given none
            return
        classes = {c.id: import_message_type(c.msgtype) for c in conns}
        for conn, timestamp, data in reader.messages(connections=conns):
            yield BagMessage(
                conn.topic, conn.msgtype, timestamp, deserialize_message(data, classes[conn.id])
            )
    finally:
        reader.close()


def grey_images(path: str | Path, topic: str) -> list[tuple[int, np.ndarray]]:
    """(header stamp in ns, grey image) of every image on ``topic``, in order."""
    from memo_ros.ros.images import image_message_to_grey

    return [
        (stamp_to_ns(m.message.header.stamp), image_message_to_grey(m.message))
        for m in read_messages(path, [topic])
    ]


def bag_topics(path: str | Path) -> dict[str, str]:
    """Topic -> type of a bag."""
    reader = open_bag(path)
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def tracked_bodies(path: str | Path) -> dict[int, tuple]:
    """Stamp (ns) -> (rotations, origins, semi_axes, lengths) of every body a tracker's bag draws.

    The bodies are those on /memo/markers of the tracker's output bag (a first pass over a
    recording, for learning its background with the person masked out).
    """
    from memo_ros.ros.body_messages import MARKERS_TOPIC, tracked_body_from_markers

    bodies = {}
    for m in read_messages(path, [MARKERS_TOPIC]):
        tracked = tracked_body_from_markers(m.message)
        if tracked is not None:
            bodies[tracked[0]] = tracked[1]
    if not bodies:
        raise BagError(f'{path} has no tracked body on /memo/markers')
    return bodies
