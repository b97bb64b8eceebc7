"""`bag play`: publish a bag's recorded serialized bytes over DDS with the recorded timing.

No message is converted: a bag played and recorded again holds the same bytes.
:class:`BagPlayer` is the reusable core (replay and the benchmarks use it).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
import sys
import tempfile
import threading
import time
from typing import Callable, Iterator, Mapping, Sequence

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import (
    Connection,
)

from memo_ros.ros.bagio import BagError, open_bag
from memo_ros.ros.dds import (
    DURABILITY,
    RELIABILITY,
    absolute_topic,
    player_segment,
    qos_profile,
    ros_session,
    stop_on_signals,
)
from memo_ros.ros.messages import MessageTypeError, import_message_type
from memo_ros.tools.bag.status import StatusLine, progress_enabled

# bytes a message may gain or lose when serialised again: writers align empty sequences and the
# end differently (rosbags and rclpy differ by 8 bytes on a JointState with two empty arrays)
CDR_SLACK = 64
PLAYER_SEGMENT_BYTES = (
    16 << 20
)  # `bag play`'s shared-memory segment: a few frames of several cameras' images


@dataclass
class PlayOptions:
    """How :class:`BagPlayer` plays a bag."""

    rate: float = 1.0  # 0: as fast as possible
    loop: bool = False
    start_offset: float = 0.0  # seconds into the bag
    topics: Sequence[str] | None = None  # bag topics to play (None: all)
    remap: Mapping[str, str] = field(default_factory=dict)  # bag topic -> published topic
    reliability: str = 'reliable'
    durability: str = 'volatile'
    qos_depth: int = 100
    wait_for_subscribers: int = 0  # matched subscriptions each publisher needs before play
    wait_timeout: float | None = 30.0  # seconds (None: forever)


@dataclass
class PlayedMessage:
    """One message as the player publishes it (passed to the hooks)."""

    topic: str  # published topic (after remapping)
    bag_topic: str
    msgtype: str
    log_time_ns: int
    data: bytes
    index: int  # messages published before this one in this pass through the bag


MessageHook = Callable[[PlayedMessage], None]


class BagPlayer:
    """Publishes the serialized messages of a rosbag2 on ``node`` with the recorded timing.

    Or faster.

    ``before_publish`` may block, e.g. for back-pressure: the playback clock stands still while it
    runs, so the timing after it is kept. ``after_publish`` sees every message once it is sent.
    """

    def __init__(
        self,
        node: Node | None,
        bag_path: str | Path,
        options: PlayOptions | None = None,
        before_publish: MessageHook | None = None,
        after_publish: MessageHook | None = None,
    ) -> None:
        self.node = node
        self.options = options or PlayOptions()
        self.before_publish = before_publish
        self.after_publish = after_publish
        self._check_options()
        self.reader = open_bag(bag_path)
        try:
            self.connections = self._select_connections()
            self.publishers, self.topics = self._create_publishers()
        except BaseException:
            self.reader.close()
            raise

    @classmethod
    def check(cls, bag_path: str | Path, options: PlayOptions) -> None:
        """Refuse what playing would refuse, before any ROS session: a bad request fails at once.

        The options, the topics asked for, every message type and each topic's first payload
        (BagError), as the player's constructor checks them, without creating publishers.
        """
        with cls(None, bag_path, options):
            pass

    def _check_options(self) -> None:
        """Refuse options no bag can be played with."""
        options = self.options
        if options.rate < 0:
            raise BagError(
                f'rate must be positive (or 0 for as fast as possible), not {options.rate}'
            )
        if options.start_offset < 0:
            raise BagError('start offset must not be negative')
        if options.reliability not in RELIABILITY or options.durability not in DURABILITY:
            raise BagError(f'unknown QoS {options.reliability}/{options.durability}')
        if options.qos_depth < 1:
            raise BagError('QoS depth must be at least 1')

    def _select_connections(self) -> list[Connection]:
        """Return the bag's connections on the requested topics.

        An error names requested topics the bag lacks.
        """
        connections = self.reader.connections
        if self.options.topics is not None:
            wanted = {absolute_topic(t) for t in self.options.topics}
            missing = wanted - {c.topic for c in connections}
            if missing:
                raise BagError(
                    f'not in the bag: {", ".join(sorted(missing))} '
                    f'(it has {", ".join(sorted({c.topic for c in connections})) or "no topics"})'
                )
            connections = [c for c in connections if c.topic in wanted]
        return connections

    def _create_publishers(self) -> tuple[dict[int, object], dict[str, str]]:
        """Return a publisher per published topic, keyed by connection id.

        And published topic -> type.
        """
        qos = qos_profile(
            self.options.reliability, self.options.qos_depth, self.options.durability
        )
        remap = {absolute_topic(k): absolute_topic(v) for k, v in self.options.remap.items()}
        by_topic: dict[str, tuple[str, object]] = {}
        publishers = {}
        for conn in self.connections:
            topic = remap.get(conn.topic, conn.topic)
            if topic in by_topic:
                msgtype, publisher = by_topic[topic]
                if msgtype != conn.msgtype:
                    raise BagError(
                        f'topic {topic} would carry two types: {msgtype} and {conn.msgtype}'
                    )
            else:
                try:
                    msg_class = import_message_type(conn.msgtype)
                except MessageTypeError as exc:
                    raise BagError(
                        f'cannot play {conn.topic}: {exc} (leave it out with --topics)'
                    ) from None
                publisher = (
                    None
                    if self.node is None
                    else self.node.create_publisher(msg_class, topic, qos)
                )  # none: only checking (check)
                by_topic[topic] = (conn.msgtype, publisher)
            self._check_payload(conn)
            publishers[conn.id] = publisher
        return publishers, {topic: msgtype for topic, (msgtype, _) in by_topic.items()}

    @property
    def start_ns(self) -> int:
        """Log time where playing starts (bag start plus the start offset)."""
        return self.reader.start_time + int(round(self.options.start_offset * 1e9))

    @property
    def end_ns(self) -> int:
        """Log time of the bag's last message."""
        return self.reader.end_time - 1

    def _check_payload(self, conn: Connection) -> None:
        """Refuse a connection whose first message is not of the type the bag's metadata names.

        Such messages reach no subscriber of the right type, or a wrong one that fails on them:
        nothing would say why.  A message read back must serialise to about its own length.
        """
        msg_class = import_message_type(conn.msgtype)
        for _, _, data in self.reader.messages(connections=[conn]):
            data = bytes(data)
            try:
                length = len(serialize_message(deserialize_message(data, msg_class)))
            except RuntimeError:  # rclpy's RMWError: the bytes do not read as msg_class
                length = -1
            if abs(length - len(data)) > max(CDR_SLACK, len(data) // 100):
                raise BagError(
                    f'{conn.topic}: its messages are not {conn.msgtype}, the type the bag '
                    'names (the first one does not read as one); leave it out with --topics'
                )
            return

    def unmatched_topics(self) -> list[str]:
        """Return the published topics with too few matched subscriptions.

        Fewer than ``options.wait_for_subscribers``.
        """
        need = self.options.wait_for_subscribers
        seen = {}
        for publisher in self.publishers.values():
            seen[publisher.topic_name] = publisher.get_subscription_count()
        return sorted(topic for topic, count in seen.items() if count < need)

    def wait_for_subscribers(
        self, stop: threading.Event | None = None, period: float = 0.02
    ) -> list[str]:
        """Wait until every publisher has its subscribers.

        The topics still lacking them on timeout or stop.
        """
        stop = stop or threading.Event()
        timeout = self.options.wait_timeout
        deadline = None if timeout is None else time.monotonic() + timeout
        missing = self.unmatched_topics()
        while missing and not stop.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                break
            stop.wait(period)
            missing = self.unmatched_topics()
        return missing

    def _messages(self) -> Iterator[tuple[Connection, int, bytes]]:
        """Return the selected messages from the start offset on, in log-time order."""
        if not self.connections:
            return iter(())
        return self.reader.messages(connections=self.connections, start=self.start_ns)

    def play_once(self, stop: threading.Event) -> int:
        """One pass through the bag with the recorded timing; the number of messages published."""
        rate = self.options.rate
        start_ns = self.start_ns
        wall_start = time.monotonic()
        count = 0
        for conn, log_time, data in self._messages():
            if stop.is_set():
                break
            if rate > 0:
                delay = wall_start + (log_time - start_ns) / 1e9 / rate - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    break
            item = PlayedMessage(
                self.publishers[conn.id].topic_name,
                conn.topic,
                conn.msgtype,
                log_time,
                data if isinstance(data, bytes) else bytes(data),
                count,
            )
            if self.before_publish is not None:
                hook_start = time.monotonic()
                self.before_publish(item)
                wall_start += time.monotonic() - hook_start
                if stop.is_set():
                    break
            self.publishers[conn.id].publish(item.data)
            count += 1
            if self.after_publish is not None:
                self.after_publish(item)
        return count

    def play(self, stop: threading.Event | None = None) -> int:
        """Play the bag (repeatedly with ``loop``) until done or ``stop`` is set.

        The number of messages published.
        """
        stop = stop or threading.Event()
        total = 0
        while not stop.is_set():
            published = self.play_once(stop)
            total += published
            if not self.options.loop or published == 0:
                break
        return total

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until reliable subscribers acknowledged everything published.

        So exiting loses nothing.
        """
        deadline = time.monotonic() + timeout
        ok = True
        for publisher in {id(p): p for p in self.publishers.values()}.values():
            left = max(deadline - time.monotonic(), 0.0)
            ok = publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and ok
        return ok

    def close(self) -> None:
        """Destroy the publishers and close the bag."""
        if self.node is not None:
            for publisher in {id(p): p for p in self.publishers.values()}.values():
                self.node.destroy_publisher(publisher)
        self.publishers = {}
        self.reader.close()

    def __enter__(self) -> 'BagPlayer':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def parse_remaps(items: Sequence[str]) -> dict[str, str]:
    """'OLD:=NEW' strings as a dict of absolute topic names."""
    remap = {}
    for item in items:
        old, sep, new = item.partition(':=')
        if not sep or not old.strip() or not new.strip():
            raise BagError(f'bad remap {item!r} (expected OLD:=NEW)')
        remap[absolute_topic(old)] = absolute_topic(new)
    return remap


def run_play(args: argparse.Namespace) -> int:
    """`bag play`: publish a bag until it ends (or forever with --loop) or a signal stops it."""
    from memo_ros.tools.cli import CliError

    options = PlayOptions(
        rate=0.0 if args.max_speed else args.rate,
        loop=args.loop,
        start_offset=args.start_offset,
        topics=args.topics,
        remap=parse_remaps(args.remap),
        reliability=args.qos,
        durability=args.durability,
        qos_depth=args.qos_depth,
        wait_for_subscribers=args.wait_for_subscribers,
        wait_timeout=args.wait_timeout,
    )
    BagPlayer.check(args.bag, options)  # a bad request fails before DDS starts
    status = StatusLine(progress_enabled(args))
    # one process publishing every camera's images needs more than Fast DDS's 512 KiB shared-memory
    # segment
    with (
        tempfile.TemporaryDirectory(prefix='memo_bag_play_') as tmp,
        player_segment(PLAYER_SEGMENT_BYTES, tmp),
        ros_session('memo_ros_bag_player') as (node, _executor),
        stop_on_signals() as stop,
    ):
        with BagPlayer(node, args.bag, options) as player:
            duration = max(player.end_ns - player.start_ns, 0) / 1e9

            def show(item: PlayedMessage) -> None:
                status.show(
                    f'playing: {(item.log_time_ns - player.start_ns) / 1e9:7.2f} / '
                    f'{duration:.2f} s, '
                    f'{item.index + 1} messages'
                )

            player.after_publish = show
            print(
                f'playing {sum(c.msgcount for c in player.connections)} messages on '
                f'{len(player.topics)} '
                f'topics from {args.bag}',
                file=sys.stderr,
            )
            missing = player.wait_for_subscribers(stop)
            if missing and not stop.is_set():
                raise CliError(
                    f'fewer than {options.wait_for_subscribers} subscriber(s) after '
                    f'{options.wait_timeout:g} s on: {", ".join(missing)}'
                )
            published = player.play(stop)
            status.close()
            if not player.flush():
                print(
                    'bag play: some subscribers did not acknowledge every message', file=sys.stderr
                )
    print(
        f'{"stopped after" if stop.is_set() else "done:"} {published} messages published',
        file=sys.stderr,
    )
    return 0
