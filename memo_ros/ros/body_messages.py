"""The tracker outputs as rclpy messages.

Joint states, part poses, RViz markers, root pose with covariance.

Shared by every node that publishes a body estimate (the articulated tracker and the walking
tracker), so both speak exactly DESIGN.md's contract.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseArray,
    PoseWithCovarianceStamped,
    Quaternion,
    Vector3,
)
import numpy as np
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.rotations import matrix_to_quat, quat_to_matrix
from memo_ros.core.vision.tracked_region import parts_from_cylinders
from memo_ros.ros.messages import stamp_to_ns

WORLD = 'world'
MARKER_NAMESPACE = 'memo_body'
MARKERS_TOPIC = '/memo/markers'  # visualization_msgs/MarkerArray: one cylinder per part
PROCESSED_TOPIC = (
    '/memo/processed'  # std_msgs/Header per frame a tracker finished, published or not
)


def stamp_from_ns(stamp_ns: int) -> Time:
    """builtin_interfaces/Time from integer nanoseconds."""
    return Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


def world_header(stamp_ns: int) -> Header:
    """Return a Header in the world frame stamped ``stamp_ns``."""
    return Header(stamp=stamp_from_ns(stamp_ns), frame_id=WORLD)


def processed_outcome(frame_id: str) -> str:
    """Return the outcome word of a /memo/processed frame_id.

    For example 'tracking' of 'tracking heading_confidence=0.62'.
    """
    return frame_id.split(' ', 1)[0]


def processed_message(stamp_ns: int, outcome: str) -> Header:
    """Return the header saying frame ``stamp_ns`` is done: replay's back-pressure.

    ``outcome`` goes in frame_id: tracking, lost, waiting, dropped...
    """
    return Header(stamp=stamp_from_ns(stamp_ns), frame_id=outcome)


def joint_state_message(stamp_ns: int, names, positions, velocities=None) -> JointState:
    """sensor_msgs/JointState in ``world`` with the generalized coordinates.

    And their time derivatives.
    """
    msg = JointState(header=world_header(stamp_ns), name=list(names))
    msg.position = [float(v) for v in positions]
    if velocities is not None:
        msg.velocity = [float(v) for v in velocities]
    return msg


def _poses(rotations: np.ndarray, origins: np.ndarray) -> list[Pose]:
    """Poses of (N, 3, 3) rotations at (N, 3) origins: one quaternion conversion for all."""
    quats = matrix_to_quat(np.asarray(rotations, float)).tolist()
    return [
        Pose(
            position=Point(x=o[0], y=o[1], z=o[2]),
            orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        for q, o in zip(quats, np.asarray(origins, float).tolist())
    ]


def pose_array_message(stamp_ns: int, rotations: np.ndarray, origins: np.ndarray) -> PoseArray:
    """geometry_msgs/PoseArray.

    One pose per part in part order (origin = proximal joint, +z along the part).
    """
    return PoseArray(header=world_header(stamp_ns), poses=_poses(rotations, origins))


def marker_array_message(
    stamp_ns: int,
    body: Body,
    rotations: np.ndarray,
    origins: np.ndarray,
    colour: tuple[float, float, float, float] = (0.2, 0.6, 1.0, 0.8),
    lifetime_s: float = 0.5,
) -> MarkerArray:
    """One CYLINDER per part, centred on the part's mid-point.

    RViz cylinders are centred, along z.
    """
    markers = []
    r, g, b, a = colour
    centres = origins + rotations[:, :, 2] * (body.lengths[:, None] / 2.0)
    sizes = np.column_stack([2 * body.semi_axes[:, :2], body.lengths]).tolist()
    for i, (name, pose) in enumerate(zip(PART_NAMES, _poses(rotations, centres))):
        m = Marker(
            header=world_header(stamp_ns),
            ns=MARKER_NAMESPACE,
            id=i,
            type=Marker.CYLINDER,
            action=Marker.ADD,
            pose=pose,
            scale=Vector3(x=sizes[i][0], y=sizes[i][1], z=sizes[i][2]),
            color=ColorRGBA(r=r, g=g, b=b, a=a),
            text=name,
        )
        m.lifetime.sec = int(lifetime_s)
        m.lifetime.nanosec = int((lifetime_s % 1.0) * 1e9)
        markers.append(m)
    return MarkerArray(markers=markers)


def root_pose_message(
    stamp_ns: int, rotation: np.ndarray, origin: np.ndarray, covariance: np.ndarray
) -> PoseWithCovarianceStamped:
    """Return the pelvis pose with its 6x6 covariance (x, y, z, rotation about x, y, z).

    Like robot_localization's output.
    """
    msg = PoseWithCovarianceStamped(header=world_header(stamp_ns))
    msg.pose.pose = _poses(rotation[None], np.asarray(origin, float)[None])[0]
    msg.pose.covariance = [float(v) for v in np.asarray(covariance, float).reshape(36)]
    return msg


def tracked_body_from_markers(msg: MarkerArray) -> tuple[int, tuple[np.ndarray, ...]] | None:
    """Return (stamp ns, (rotations, origins, semi_axes, lengths)) of a /memo/markers body.

    The body the message draws; None when it has no cylinders (the inverse of
    :func:`marker_array_message` for the parts).
    """
    cylinders = sorted((m for m in msg.markers if m.type == m.CYLINDER), key=lambda m: m.id)
    if not cylinders:
        return None
    centres = np.array(
        [[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in cylinders]
    )
    rotations = quat_to_matrix(
        np.array(
            [
                [
                    m.pose.orientation.x,
                    m.pose.orientation.y,
                    m.pose.orientation.z,
                    m.pose.orientation.w,
                ]
                for m in cylinders
            ]
        )
    )
    scales = np.array([[m.scale.x, m.scale.y, m.scale.z] for m in cylinders])
    origins, semi_axes, lengths = parts_from_cylinders(centres, rotations, scales)
    return stamp_to_ns(cylinders[0].header.stamp), (rotations, origins, semi_axes, lengths)
