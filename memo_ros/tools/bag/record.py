"""`bag record`: write the bytes received on the wire into an mcap bag (metadata version 9).

Message definitions come from the Jazzy typestore; :class:`BagRecorder` is the reusable core.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
import re
import sys
import threading
import time
from typing import Callable, Sequence

from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription
from rosbags.interfaces import (
    Connection,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from memo_ros.ros.bagio import STORAGE_PLUGINS, TYPESTORE, BagError, BagWriter
from memo_ros.ros.dds import (
    absolute_topic,
    adapted_qos,
    ros_session,
    stop_on_signals,
    topic_types,
)
from memo_ros.ros.messages import MessageTypeError, import_message_type
from memo_ros.tools.bag.status import StatusLine, progress_enabled

DISCOVERY_PERIOD = 0.1  # seconds between two looks at the graph while topics are missing

INFINITE_NS = 2**63 - 1  # rosbags' 'infinite' QoS duration, ns


ALL_TOPICS_PERIOD = 0.5  # seconds between two looks at the graph with --all


def rosbags_qos(profile) -> Qos:
    """Return an rclpy QoSProfile, as a publisher offers it, as the rosbags Qos of the metadata."""

    def duration(value) -> QosTime:
        ns = value.nanoseconds
        if ns >= INFINITE_NS or ns < 0:
            return QosTime(2147483647, 4294967295)
        return QosTime(*divmod(ns, 1_000_000_000))

    def enum(kind, value, default):
        try:
            return kind(int(value))
        except ValueError:
            return default

    return Qos(
        history=enum(QosHistory, profile.history, QosHistory.UNKNOWN),
        depth=int(profile.depth),
        reliability=enum(QosReliability, profile.reliability, QosReliability.UNKNOWN),
        durability=enum(QosDurability, profile.durability, QosDurability.UNKNOWN),
        deadline=duration(profile.deadline),
        lifespan=duration(profile.lifespan),
        liveliness=enum(QosLiveliness, profile.liveliness, QosLiveliness.UNKNOWN),
        liveliness_lease_duration=duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def is_hidden(topic: str) -> bool:
    """Return True for hidden topics (a name component starting with '_').

    Which --all leaves out like ros2 bag.
    """
    return any(part.startswith('_') for part in topic.split('/'))


@dataclass
class RecordOptions:
    """What :class:`BagRecorder` records and how."""

    topics: Sequence[str] = ()  # explicit topics (ignored with all_topics)
    all_topics: bool = False
    exclude: str | None = None  # regex of topics --all leaves out
    storage: str = 'mcap'
    reliability: str = 'auto'  # auto: adapt to the publishers like rosbag2
    durability: str = 'auto'
    qos_depth: int = 100
    max_messages: int | None = None


class BagRecorder:
    """Raw subscriptions on ``node`` whose received bytes go into a rosbag2.

    Stamped with their receive time.

    Call :meth:`discover` periodically: it subscribes to requested topics as they appear in the
    graph (with ``all_topics``, to every new topic).
    """

    def __init__(
        self,
        node: Node,
        out: str | Path,
        options: RecordOptions,
        on_subscribe: Callable[[str, str, QoSProfile], None] | None = None,
        on_skip: Callable[[str, str], None] | None = None,
        on_match: Callable[[str, int], None] | None = None,
    ) -> None:
        self.node = node
        self.out = Path(out)
        self.options = options
        self.on_subscribe = on_subscribe
        self.on_skip = on_skip
        self.on_match = on_match
        self.matched: set[str] = set()
        self.wanted = {absolute_topic(t) for t in options.topics}
        self._exclude = re.compile(options.exclude) if options.exclude else None
        self.subscriptions: dict[str, Subscription] = {}
        self.counts: dict[str, int] = {}
        self.skipped: dict[str, str] = {}
        self.count = 0
        self.first_receive: float | None = None
        self.last_receive: float | None = None
        if options.storage not in STORAGE_PLUGINS:
            raise BagError(f'unknown storage {options.storage!r} (mcap or sqlite3)')
        if self.out.exists():
            raise BagError(f'output {self.out} exists already; choose another name or remove it')
        try:
            self.writer = BagWriter(self.out, options.storage)
        except Exception as exc:  # noqa: BLE001 - rosbags and the OS raise several types
            raise BagError(f'cannot write bag {self.out}: {exc}') from None
        self._closed = False

    @property
    def done(self) -> bool:
        """True once ``max_messages`` have been written."""
        limit = self.options.max_messages
        return limit is not None and self.count >= limit

    @property
    def missing(self) -> list[str]:
        """Requested topics not subscribed yet."""
        return sorted(self.wanted - set(self.subscriptions) - set(self.skipped))

    def _candidates(self) -> dict[str, list[str]]:
        """Topics in the graph this recorder should subscribe to now."""
        graph = topic_types(self.node)
        if not self.options.all_topics:
            return {t: graph[t] for t in self.wanted if t in graph and t not in self.subscriptions}
        return {
            t: types
            for t, types in graph.items()
            if t not in self.subscriptions
            and t not in self.skipped
            and not is_hidden(t)
            and not (self._exclude and self._exclude.search(t))
        }

    def discover(self) -> list[str]:
        """Subscribe to requested topics that appeared in the graph; return the new ones."""
        added = []
        for topic, types in sorted(self._candidates().items()):
            reason = self._subscribe(topic, types)
            if reason is None:
                added.append(topic)
            elif not self.options.all_topics:
                raise BagError(f'cannot record {topic}: {reason}')
            else:
                self.skipped[topic] = reason
                if self.on_skip is not None:
                    self.on_skip(topic, reason)
        return added

    def check_matches(self) -> list[str]:
        """Topics whose subscription matched its first publisher since the last call.

        Matched is what a reader needs before it can receive: seeing a topic in the graph is not
        enough, the two endpoints may still be exchanging their descriptions.
        """
        new = []
        for topic, subscription in self.subscriptions.items():
            if topic in self.matched:
                continue
            count = subscription.get_publisher_count()
            if count:
                self.matched.add(topic)
                new.append(topic)
                if self.on_match is not None:
                    self.on_match(topic, count)
        return new

    def _subscribe(self, topic: str, types: list[str]) -> str | None:
        """Subscribe raw to ``topic`` and register it in the bag.

        Why not, when it cannot be recorded.
        """
        if len(types) != 1:
            return f'it carries several types ({", ".join(types)})'
        msgtype = types[0]
        if msgtype not in TYPESTORE.types:
            return (
                f'type {msgtype} is unknown to the Jazzy type store (no message definition to '
                'store)'
            )
        try:
            msg_class = import_message_type(msgtype)
        except MessageTypeError as exc:
            return str(exc)
        offered = [
            rosbags_qos(info.qos_profile) for info in self.node.get_publishers_info_by_topic(topic)
        ]
        qos = adapted_qos(
            self.node,
            topic,
            self.options.qos_depth,
            self.options.reliability,
            self.options.durability,
        )
        connection = self.writer.add_connection(topic, msgtype, offered)
        self.subscriptions[topic] = self.node.create_subscription(
            msg_class, topic, self._callback(topic, connection), qos, raw=True
        )
        self.counts[topic] = 0
        if self.on_subscribe is not None:
            self.on_subscribe(topic, msgtype, qos)
        return None

    def _callback(self, topic: str, connection: Connection) -> Callable[[bytes, dict], None]:
        """Return the subscription callback writing ``topic``'s bytes with their receive time."""

        def on_message(data: bytes, info: dict) -> None:
            if self.done or self._closed:
                return
            stamp = info.get('received_timestamp') or time.time_ns()
            self.writer.write_raw(connection, stamp, data)
            self.count += 1
            self.counts[topic] += 1
            self.last_receive = time.monotonic()
            if self.first_receive is None:
                self.first_receive = self.last_receive

        return on_message

    def close(self) -> None:
        """Destroy the subscriptions and finish the bag (metadata, mcap summary)."""
        if self._closed:
            return
        self._closed = True
        for subscription in self.subscriptions.values():
            self.node.destroy_subscription(subscription)
        self.writer.close()

    def __enter__(self) -> 'BagRecorder':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def record_until(
    recorder: BagRecorder,
    executor: Executor,
    stop: threading.Event,
    duration: float | None = None,
    idle_timeout: float | None = None,
    status: StatusLine | None = None,
) -> str:
    """Spin and discover until a stop condition; the reason recording stopped."""
    start = time.monotonic()
    next_look = start
    while True:
        now = time.monotonic()
        if stop.is_set():
            return 'interrupted'
        if recorder.done:
            return f'{recorder.count} messages recorded'
        if duration is not None and now - start >= duration:
            return f'{duration:g} s elapsed'
        if (
            idle_timeout is not None
            and recorder.last_receive is not None
            and now - recorder.last_receive >= idle_timeout
        ):
            return f'no message for {idle_timeout:g} s'
        if now >= next_look and (recorder.options.all_topics or recorder.missing):
            recorder.discover()
            period = ALL_TOPICS_PERIOD if recorder.options.all_topics else DISCOVERY_PERIOD
            next_look = now + period
        executor.spin_once(timeout_sec=0.05)
        if len(recorder.matched) < len(recorder.subscriptions):
            recorder.check_matches()
        if status is not None:
            status.show(
                f'recording: {recorder.count} messages on {len(recorder.subscriptions)} topics, '
                f'{now - start:.1f} s'
            )


def run_record(args: argparse.Namespace) -> int:
    """`bag record`: record until a signal or a stop condition, then close the bag properly."""
    from memo_ros.tools.cli import CliError

    if not args.topics and not args.all:
        raise CliError('name the topics to record, or use --all')
    if args.topics and args.all:
        raise CliError('give either topics or --all, not both')
    from rclpy.validate_topic_name import InvalidTopicNameException, validate_topic_name

    for topic in args.topics:
        try:
            validate_topic_name(topic)
        except InvalidTopicNameException as exc:
            reason = str(exc).splitlines()[0].split(':', 1)[-1].strip()
            raise CliError(f'{topic!r} is not a valid topic name ({reason})') from None
    if args.exclude:
        try:
            re.compile(args.exclude)
        except re.error as exc:
            raise CliError(f'bad --exclude regex: {exc}') from None
    if args.output.exists():
        raise CliError(f'output {args.output} exists already; choose another name or remove it')
    options = RecordOptions(
        topics=args.topics,
        all_topics=args.all,
        exclude=args.exclude,
        storage=args.storage,
        reliability=args.qos,
        qos_depth=args.qos_depth,
        max_messages=args.max_messages,
    )

    def subscribed(topic: str, msgtype: str, qos: QoSProfile) -> None:
        print(f'recording {topic} ({msgtype}, {qos.reliability.name.lower()})', file=sys.stderr)

    def skipped(topic: str, reason: str) -> None:
        print(f'bag record: not recording {topic}: {reason}', file=sys.stderr)

    def matched(topic: str, count: int) -> None:
        print(f'matched {topic} ({count} publisher{"s" * (count != 1)})', file=sys.stderr)

    status = StatusLine(progress_enabled(args))
    with ros_session('memo_ros_bag_recorder') as (node, executor), stop_on_signals() as stop:
        with BagRecorder(node, args.output, options, subscribed, skipped, matched) as recorder:
            reason = record_until(
                recorder, executor, stop, args.duration, args.idle_timeout, status
            )
            status.close()
    per_topic = ', '.join(f'{t}: {n}' for t, n in sorted(recorder.counts.items()))
    print(
        f'stopped ({reason}): {recorder.count} messages written to {args.output}'
        + (f' ({per_topic})' if per_topic else ''),
        file=sys.stderr,
    )
    if recorder.missing:
        print(f'bag record: never saw {", ".join(recorder.missing)}', file=sys.stderr)
    return 0
