"""DDS plumbing shared by the tools.

a ROS session, QoS by name or adapted to publishers, topic discovery, stop signals.

Tools own their ``rclpy.Context`` (never the global one) and install their own SIGINT/SIGTERM
handlers, so a signal only asks the tool to stop and the tool can close bags and shut down
executor, node and context in that order.
"""

from __future__ import annotations

from contextlib import contextmanager
import signal
import threading
import time
from typing import Callable, Iterator

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

RELIABILITY = {
    'reliable': ReliabilityPolicy.RELIABLE,
    'best_effort': ReliabilityPolicy.BEST_EFFORT,
}
DURABILITY = {
    'volatile': DurabilityPolicy.VOLATILE,
    'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
}


def qos_profile(
    reliability: str = 'reliable', depth: int = 10, durability: str = 'volatile'
) -> QoSProfile:
    """Return a keep-last QoS profile from the names used on the command line."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=RELIABILITY[reliability],
        durability=DURABILITY[durability],
    )


def adapted_qos(
    node: Node, topic: str, depth: int, reliability: str = 'auto', durability: str = 'auto'
) -> QoSProfile:
    """Return a subscription profile that matches every current publisher of ``topic``.

    'auto' adapts like rosbag2.

    Reliable only when all publishers are reliable, transient-local only when all are, so a
    subscriber neither misses best-effort publishers nor latched messages.
    """
    offered = [info.qos_profile for info in node.get_publishers_info_by_topic(topic)]
    if reliability == 'auto':
        reliable = bool(offered) and all(
            q.reliability == ReliabilityPolicy.RELIABLE for q in offered
        )
        reliability = 'reliable' if reliable else 'best_effort'
    if durability == 'auto':
        latched = bool(offered) and all(
            q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered
        )
        durability = 'transient_local' if latched else 'volatile'
    return qos_profile(reliability, depth, durability)


def absolute_topic(name: str) -> str:
    """Return a topic name resolved against the root namespace.

    'cam/image_raw' -> '/cam/image_raw'.
    """
    name = name.strip()
    return name if name.startswith('/') else '/' + name


def topic_types(node: Node) -> dict[str, list[str]]:
    """Topic name -> message types currently seen in the graph."""
    return dict(node.get_topic_names_and_types())


def wait_for_topic_type(
    node: Node,
    topic: str,
    timeout: float | None,
    stop: threading.Event | None = None,
    period: float = 0.1,
) -> str | None:
    """Return the type of ``topic`` once a publisher or subscriber announces it.

    None on timeout or stop.
    """
    deadline = None if timeout is None else time.monotonic() + timeout
    while stop is None or not stop.is_set():
        types = topic_types(node).get(topic)
        if types:
            return types[0]
        if deadline is not None and time.monotonic() >= deadline:
            return None
        if stop is not None:
            stop.wait(period)
        else:
            time.sleep(period)
    return None


@contextmanager
def ros_session(
    node_name: str, domain_id: int | None = None
) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """Return a node and its executor on a private context.

    Shut down executor, node, context on exit.
    """
    context = Context()
    rclpy.init(
        context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO
    )
    node = executor = None
    try:
        node = Node(
            node_name, context=context, start_parameter_services=False, enable_rosout=False
        )
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        yield node, executor
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        context.try_shutdown()


class MatchedOnDiagnostics:
    """The matched endpoints the graph's nodes report on /diagnostics (``NodeHealth.matched``).

    A player's or recorder's own half of a match says nothing of the node's: DDS delivers only
    once both halves matched, so a tool waits for the node's half here before it sends.
    """

    def __init__(self, node: Node) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self._counts: dict[tuple[str, str], int] = {}  # (node, key) -> matched endpoints
        self._lock = threading.Lock()
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50)

    def _on_diagnostics(self, msg) -> None:
        with self._lock:
            for status in msg.status:
                for kv in status.values:
                    if kv.key.startswith(('subscribers.', 'publishers.')) and kv.value.isdigit():
                        self._counts[(status.name, kv.key)] = int(kv.value)

    def missing_in_graph(self, node: Node, inputs, outputs) -> list[str]:
        """Return the matches the nodes do not report yet, of those the graph shows ``node``.

        Every publisher the graph has of each of ``inputs`` (a player's among them) and every
        subscriber of each of ``outputs`` (a recorder's among them), at least one each; the
        topics every node has (/diagnostics, ...) are not reported and left out.
        """
        from memo_ros.ros.health import INFRASTRUCTURE_TOPICS

        wanted = {f'publishers.{t}': max(1, node.count_publishers(t)) for t in inputs}
        wanted |= {
            f'subscribers.{t}': max(1, node.count_subscribers(t))
            for t in outputs
            if t not in INFRASTRUCTURE_TOPICS
        }
        return self.missing(wanted)

    def missing(self, wanted: dict[str, int]) -> list[str]:
        """Return the keys of ``wanted`` that no node reports with at least that count yet.

        Keys as the nodes report them: ``publishers.<topic>``, ``subscribers.<topic>``.
        """
        with self._lock:
            counts = dict(self._counts)
        have: dict[str, int] = {}
        for (_node, key), n in counts.items():
            have[key] = max(have.get(key, 0), n)
        return [key for key, n in wanted.items() if have.get(key, 0) < n]


@contextmanager
def stop_on_signals(on_stop: Callable[[], None] | None = None) -> Iterator[threading.Event]:
    """Return an event that SIGINT and SIGTERM set (instead of raising), so loops finish cleanly.

    Handlers restored on exit.
    """
    stop = threading.Event()

    def handler(signum, frame) -> None:
        stop.set()
        if on_stop is not None:
            on_stop()

    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


PROFILES_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
XML_QOS_VARIABLE = 'RMW_FASTRTPS_USE_QOS_FROM_XML'
NODE_PROFILE = 'fastdds_node_memory.xml'  # config/: DYNAMIC history memory for the nodes
# One process playing every camera, where each camera would have its own driver: Fast DDS's default
# 512 KiB
# shared-memory segment per participant holds one 640x480 image, so the other cameras' images of a
# frame are
# lost in the player; reliable ones are repaired about a second later, which stalls a replay.
LARGE_SEGMENT_PROFILE = """<?xml version="1.0" encoding="UTF-8"?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor><transport_id>player_shm</transport_id><type>SHM</type>
      <segment_size>{segment_size}</segment_size></transport_descriptor>
    <transport_descriptor><transport_id>player_udp</transport_id><type>UDPv4</type>{udp_whitelist}</transport_descriptor>
  </transport_descriptors>
  <participant profile_name="memo_player" is_default_profile="true">
    <rtps><userTransports><transport_id>player_shm</transport_id><transport_id>player_udp</transport_id>
      </userTransports><useBuiltinTransports>false</useBuiltinTransports></rtps>
  </participant>
</profiles>
"""


PLAYER_SEGMENT_FRAMES = (
    4  # frames of every camera (up to 4 bytes a pixel) a player's segment holds
)


def use_node_dds_profile() -> bool:
    """Have this process's Fast DDS free each message's buffer once taken (see the XML).

    Unless the user configured Fast DDS profiles himself (a profiles file or
    RMW_FASTRTPS_USE_QOS_FROM_XML) or set MEMO_ROS_NODE_DDS_PROFILE=off.  Call before rclpy.init;
    returns whether it applied.
    """
    import os

    from memo_ros.paths import config_path

    if any(
        os.environ.get(v) is not None
        for v in (PROFILES_VARIABLE, 'FASTDDS_DEFAULT_PROFILES_FILE', XML_QOS_VARIABLE)
    ):
        return False
    if os.environ.get('MEMO_ROS_NODE_DDS_PROFILE', 'on') == 'off':
        return False
    os.environ[PROFILES_VARIABLE] = str(config_path(NODE_PROFILE))
    os.environ[XML_QOS_VARIABLE] = '1'  # the XML's memory policy and publication mode only
    return True


def player_segment_bytes(cameras) -> int:
    """Return the shared-memory segment for one process playing ``cameras``.

    a few frames of all, at least 8 MiB.
    """
    return max(PLAYER_SEGMENT_FRAMES * sum(4 * c.width * c.height for c in cameras), 8 << 20)


@contextmanager
def player_segment(segment_bytes: int, directory, localhost_only: bool = False) -> Iterator[bool]:
    """For the participants this process creates inside.

    a shared-memory segment of ``segment_bytes`` (and, ``localhost_only``, UDP on the loopback
    interface alone, for a graph on this host).

    Only when the user configured no Fast DDS transports (a profiles file,
    FASTDDS_BUILTIN_TRANSPORTS); static peers (ROS_STATIC_PEERS) still apply, rmw adds them to
    the profile's participant. Yields whether it applied.  The nodes, other
    processes, keep their defaults.
    """
    import os
    from pathlib import Path

    configured = any(os.environ.get(v) for v in (PROFILES_VARIABLE, 'FASTDDS_BUILTIN_TRANSPORTS'))
    if configured:
        yield False
        return
    profile = Path(directory) / 'memo_player_profile.xml'
    whitelist = (
        '<interfaceWhiteList><address>127.0.0.1</address></interfaceWhiteList>'
        if localhost_only
        else ''
    )
    profile.write_text(
        LARGE_SEGMENT_PROFILE.format(segment_size=int(segment_bytes), udp_whitelist=whitelist)
    )
    os.environ[PROFILES_VARIABLE] = str(profile)
    try:
        yield True
    finally:
        os.environ.pop(PROFILES_VARIABLE, None)
