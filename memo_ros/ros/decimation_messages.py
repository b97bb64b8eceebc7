"""/memo/decimation: the frames every node keeps under load, as the tracker announces them."""

from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from memo_ros.core.latency.decimation import CHANGES_KEPT, Decimation, DecimationSchedule
from memo_ros.ros.body_messages import stamp_from_ns
from memo_ros.ros.messages import stamp_to_ns

DECIMATION_TOPIC = '/memo/decimation'
# reliable and kept for a node that starts late: it sheds the same frames as the others at once
DECIMATION_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=CHANGES_KEPT,
)


def decimation_message(decimation: Decimation) -> Header:
    """Return the announcement: from its stamp on; frame_id ``every=N period_ns=P origin_ns=O``."""
    return Header(stamp=stamp_from_ns(decimation.from_ns), frame_id=decimation.to_text())


def count_shed(health, schedule: DecimationSchedule, stamp_ns: int, consequence: str) -> None:
    """Count a frame the announced decimation leaves out (``dropped.shed``), with its log line."""
    health.drop(
        'shed',
        f'the tracker keeps one frame in {schedule.at(stamp_ns).every} under load '
        f'({DECIMATION_TOPIC}): {consequence}',
    )


def follow_decimation(node: Node, schedule: DecimationSchedule, health) -> None:
    """Subscribe ``node`` to the announcements; each goes into ``schedule``.

    One that cannot be read is counted (bad_decimation) and ignored: the node keeps the frames it
    kept.
    """

    def on_announcement(msg: Header) -> None:
        try:
            schedule.add(Decimation.from_text(stamp_to_ns(msg.stamp), msg.frame_id))
        except ValueError as exc:
            health.drop('bad_decimation', f'{DECIMATION_TOPIC} ignored: {exc}')
            return
        health.set('decimation', schedule.changes[-1].every)

    node.create_subscription(
        Header,
        DECIMATION_TOPIC,
        health.guard(on_announcement, 'decimation callback'),
        DECIMATION_QOS,
    )
