"""Inspect, play and record rosbag2 files over DDS, byte for byte (`bag info|play|record`).

``play`` publishes the recorded serialized bytes with the recorded timing and
``record`` writes the bytes received on the wire, so no message is ever
converted: a bag played and recorded again holds the same bytes.  Bags are
read with ``rosbags`` (any Jazzy bag, mcap or sqlite3) and written as mcap
with metadata version 9, with message definitions from the Jazzy typestore.
:class:`BagPlayer` and :class:`BagRecorder` are the reusable cores.
"""
from __future__ import annotations

import argparse
import re
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator, Mapping, Sequence

import yaml
from rclpy.duration import Duration
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from memo_ros.ros.dds import (DURABILITY, RELIABILITY, absolute_topic, adapted_qos, player_segment, qos_profile,
                              ros_session, stop_on_signals, topic_types)
from memo_ros.ros.messages import MessageTypeError, import_message_type
from memo_ros.ros.bagio import BagError, open_bag

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
STORAGE_PLUGINS = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
STATUS_PERIOD = 0.2          # seconds between two updates of the terminal status line
DISCOVERY_PERIOD = 0.1       # seconds between two looks at the graph while topics are missing
ALL_TOPICS_PERIOD = 0.5      # seconds between two looks at the graph with --all
PLAYER_SEGMENT_BYTES = 16 << 20   # `bag play`'s shared-memory segment: a few frames of several cameras' images
INFINITE_NS = 2**63 - 1


# ----------------------------------------------------------------------------- reading and info

def storage_of(path: Path) -> tuple[str, list[Path]]:
    """Storage id ('mcap' or 'sqlite3') and data files of a bag directory or storage file."""
    if path.is_dir():
        metadata = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        files = [path / Path(name).name for name in metadata.get('relative_file_paths', [])]
        return str(metadata.get('storage_identifier', '?')), files
    return {'.mcap': 'mcap', '.db3': 'sqlite3'}.get(path.suffix, path.suffix), [path]


@dataclass
class TopicSummary:
    """One topic of a bag."""

    topic: str
    msgtype: str
    count: int
    serialization_format: str


@dataclass
class BagSummary:
    """What ``bag info`` shows."""

    path: Path
    storage: str
    files: list[Path]
    size_bytes: int
    ros_distro: str
    start_ns: int
    end_ns: int
    message_count: int
    topics: list[TopicSummary]

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns


def bag_summary(path: str | Path) -> BagSummary:
    """Storage, time span, message count and per-topic type and count of a bag."""
    path = Path(path)
    reader = open_bag(path)
    try:
        storage, files = storage_of(path)
        topics = [TopicSummary(name, info.msgtype or ', '.join(sorted({c.msgtype for c in info.connections})),
                               info.msgcount, info.connections[0].ext.serialization_format if info.connections else '')
                  for name, info in reader.topics.items()]
        count = reader.message_count
        start = reader.start_time if count else 0
        end = reader.end_time - 1 if count else 0
        return BagSummary(path, storage, files, sum(f.stat().st_size for f in files if f.exists()),
                          reader.ros_distro or '', start, end, count, topics)
    finally:
        reader.close()


def format_stamp(stamp_ns: int) -> str:
    """'2026-01-01T00:00:00.000000000Z (1767225600.000000000)': UTC ISO time and the raw stamp."""
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    iso = datetime.fromtimestamp(sec, tz=timezone.utc).strftime('%Y-%m-%dT%H:%M:%S')
    return f'{iso}.{nsec:09d}Z ({sec}.{nsec:09d})'


def format_size(size: int) -> str:
    """A byte count for humans (KiB, MiB, ...)."""
    value = float(size)
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if value < 1024 or unit == 'GiB':
            return f'{value:.0f} {unit}' if unit == 'B' else f'{value:.1f} {unit}'
        value /= 1024
    return f'{size} B'


def format_summary(summary: BagSummary) -> str:
    """The text of ``bag info``, laid out like ``ros2 bag info``."""
    width = max([len(t.topic) for t in summary.topics] + [0])
    type_width = max([len(t.msgtype) for t in summary.topics] + [0])
    lines = [
        f'Path:              {summary.path}',
        f'Files:             {", ".join(f.name for f in summary.files)}',
        f'Bag size:          {format_size(summary.size_bytes)}',
        f'Storage id:        {summary.storage}',
        f'ROS distro:        {summary.ros_distro or "unknown"}',
        f'Duration:          {summary.duration_ns / 1e9:.9f} s',
        f'Start:             {format_stamp(summary.start_ns) if summary.message_count else "-"}',
        f'End:               {format_stamp(summary.end_ns) if summary.message_count else "-"}',
        f'Messages:          {summary.message_count}',
        f'Topics:            {len(summary.topics)}',
    ]
    for t in sorted(summary.topics, key=lambda t: t.topic):
        lines.append(f'  {t.topic:<{width}} | Type: {t.msgtype:<{type_width}} | Count: {t.count:>7} | '
                     f'Serialization Format: {t.serialization_format}')
    return '\n'.join(lines)


# ----------------------------------------------------------------------------- play

@dataclass
class PlayOptions:
    """How :class:`BagPlayer` plays a bag."""

    rate: float = 1.0                       # 0: as fast as possible
    loop: bool = False
    start_offset: float = 0.0               # seconds into the bag
    topics: Sequence[str] | None = None     # bag topics to play (None: all)
    remap: Mapping[str, str] = field(default_factory=dict)   # bag topic -> published topic
    reliability: str = 'reliable'
    durability: str = 'volatile'
    qos_depth: int = 100
    wait_for_subscribers: int = 0           # matched subscriptions each publisher needs before play
    wait_timeout: float | None = 30.0       # seconds (None: forever)


@dataclass
class PlayedMessage:
    """One message as the player publishes it (passed to the hooks)."""

    topic: str          # published topic (after remapping)
    bag_topic: str
    msgtype: str
    log_time_ns: int
    data: bytes
    index: int          # messages published before this one in this pass through the bag


MessageHook = Callable[[PlayedMessage], None]


class BagPlayer:
    """Publishes the serialized messages of a rosbag2 on ``node`` with the recorded timing (or faster).

    ``before_publish`` may block, e.g. for back-pressure: the playback clock
    stands still while it runs, so the timing after it is kept.
    ``after_publish`` sees every message once it is sent.
    """

    def __init__(self, node: Node, bag_path: str | Path, options: PlayOptions | None = None,
                 before_publish: MessageHook | None = None, after_publish: MessageHook | None = None) -> None:
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

    def _check_options(self) -> None:
        """Refuse options no bag can be played with."""
        options = self.options
        if options.rate < 0:
            raise BagError(f'rate must be positive (or 0 for as fast as possible), not {options.rate}')
        if options.start_offset < 0:
            raise BagError('start offset must not be negative')
        if options.reliability not in RELIABILITY or options.durability not in DURABILITY:
            raise BagError(f'unknown QoS {options.reliability}/{options.durability}')
        if options.qos_depth < 1:
            raise BagError('QoS depth must be at least 1')

    def _select_connections(self) -> list[Connection]:
        """The bag's connections on the requested topics (an error names requested topics the bag lacks)."""
        connections = self.reader.connections
        if self.options.topics is not None:
            wanted = {absolute_topic(t) for t in self.options.topics}
            missing = wanted - {c.topic for c in connections}
            if missing:
                raise BagError(f'not in the bag: {", ".join(sorted(missing))} '
                               f'(it has {", ".join(sorted({c.topic for c in connections})) or "no topics"})')
            connections = [c for c in connections if c.topic in wanted]
        return connections

    def _create_publishers(self) -> tuple[dict[int, object], dict[str, str]]:
        """A publisher per published topic, keyed by connection id; and published topic -> type."""
        qos = qos_profile(self.options.reliability, self.options.qos_depth, self.options.durability)
        remap = {absolute_topic(k): absolute_topic(v) for k, v in self.options.remap.items()}
        by_topic: dict[str, tuple[str, object]] = {}
        publishers = {}
        for conn in self.connections:
            topic = remap.get(conn.topic, conn.topic)
            if topic in by_topic:
                msgtype, publisher = by_topic[topic]
                if msgtype != conn.msgtype:
                    raise BagError(f'topic {topic} would carry two types: {msgtype} and {conn.msgtype}')
            else:
                try:
                    msg_class = import_message_type(conn.msgtype)
                except MessageTypeError as exc:
                    raise BagError(f'cannot play {conn.topic}: {exc} (leave it out with --topics)') from None
                publisher = self.node.create_publisher(msg_class, topic, qos)
                by_topic[topic] = (conn.msgtype, publisher)
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

    def unmatched_topics(self) -> list[str]:
        """Published topics with fewer matched subscriptions than ``options.wait_for_subscribers``."""
        need = self.options.wait_for_subscribers
        seen = {}
        for publisher in self.publishers.values():
            seen[publisher.topic_name] = publisher.get_subscription_count()
        return sorted(topic for topic, count in seen.items() if count < need)

    def wait_for_subscribers(self, stop: threading.Event | None = None, period: float = 0.02) -> list[str]:
        """Wait until every publisher has its subscribers; the topics still lacking them on timeout or stop."""
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
        """The selected messages from the start offset on, in log-time order."""
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
            item = PlayedMessage(self.publishers[conn.id].topic_name, conn.topic, conn.msgtype, log_time,
                                 data if isinstance(data, bytes) else bytes(data), count)
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
        """Play the bag (repeatedly with ``loop``) until done or ``stop`` is set; the number of messages published."""
        stop = stop or threading.Event()
        total = 0
        while not stop.is_set():
            published = self.play_once(stop)
            total += published
            if not self.options.loop or published == 0:
                break
        return total

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until reliable subscribers acknowledged everything published (so exiting loses nothing)."""
        deadline = time.monotonic() + timeout
        ok = True
        for publisher in {id(p): p for p in self.publishers.values()}.values():
            left = max(deadline - time.monotonic(), 0.0)
            ok = publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and ok
        return ok

    def close(self) -> None:
        """Destroy the publishers and close the bag."""
        for publisher in {id(p): p for p in self.publishers.values()}.values():
            self.node.destroy_publisher(publisher)
        self.publishers = {}
        self.reader.close()

    def __enter__(self) -> 'BagPlayer':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class StatusLine:
    """One stderr line rewritten with \\r at most five times a second (only when enabled)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._last = 0.0
        self._width = 0

    def show(self, text: str, force: bool = False) -> None:
        """Rewrite the line with ``text`` unless it was rewritten less than STATUS_PERIOD ago."""
        now = time.monotonic()
        if not self.enabled or (not force and now - self._last < STATUS_PERIOD):
            return
        self._last = now
        sys.stderr.write(f'\r{text:<{self._width}}')
        sys.stderr.flush()
        self._width = max(self._width, len(text))

    def close(self) -> None:
        """End the line so later output starts on a fresh one."""
        if self.enabled and self._width:
            sys.stderr.write('\n')
            sys.stderr.flush()


def parse_remaps(items: Sequence[str]) -> dict[str, str]:
    """'OLD:=NEW' strings as a dict of absolute topic names."""
    remap = {}
    for item in items:
        old, sep, new = item.partition(':=')
        if not sep or not old.strip() or not new.strip():
            raise BagError(f'bad remap {item!r} (expected OLD:=NEW)')
        remap[absolute_topic(old)] = absolute_topic(new)
    return remap


# ----------------------------------------------------------------------------- record

def rosbags_qos(profile) -> Qos:
    """An rclpy QoSProfile (as offered by a publisher) as the rosbags Qos written into the metadata."""
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
        history=enum(QosHistory, profile.history, QosHistory.UNKNOWN), depth=int(profile.depth),
        reliability=enum(QosReliability, profile.reliability, QosReliability.UNKNOWN),
        durability=enum(QosDurability, profile.durability, QosDurability.UNKNOWN),
        deadline=duration(profile.deadline), lifespan=duration(profile.lifespan),
        liveliness=enum(QosLiveliness, profile.liveliness, QosLiveliness.UNKNOWN),
        liveliness_lease_duration=duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


def is_hidden(topic: str) -> bool:
    """True for hidden topics (a name component starting with '_'), which --all leaves out like ros2 bag."""
    return any(part.startswith('_') for part in topic.split('/'))


@dataclass
class RecordOptions:
    """What :class:`BagRecorder` records and how."""

    topics: Sequence[str] = ()              # explicit topics (ignored with all_topics)
    all_topics: bool = False
    exclude: str | None = None              # regex of topics --all leaves out
    storage: str = 'mcap'
    reliability: str = 'auto'               # auto: adapt to the publishers like rosbag2
    durability: str = 'auto'
    qos_depth: int = 100
    max_messages: int | None = None


class BagRecorder:
    """Raw subscriptions on ``node`` whose received bytes go into a rosbag2, stamped with their receive time.

    Call :meth:`discover` periodically: it subscribes to requested topics as they
    appear in the graph (with ``all_topics``, to every new topic).
    """

    def __init__(self, node: Node, out: str | Path, options: RecordOptions,
                 on_subscribe: Callable[[str, str, QoSProfile], None] | None = None,
                 on_skip: Callable[[str, str], None] | None = None) -> None:
        self.node = node
        self.out = Path(out)
        self.options = options
        self.on_subscribe = on_subscribe
        self.on_skip = on_skip
        self.wanted = {absolute_topic(t) for t in options.topics}
        self._exclude = re.compile(options.exclude) if options.exclude else None
        self.subscriptions: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self.skipped: dict[str, str] = {}
        self.count = 0
        self.first_receive: float | None = None
        self.last_receive: float | None = None
        if options.storage not in STORAGE_PLUGINS:
            raise BagError(f'unknown storage {options.storage!r} (mcap or sqlite3)')
        if self.out.exists():
            raise BagError(f'output {self.out} exists already; choose another name or remove it')
        self.writer = Writer(self.out, version=9, storage_plugin=STORAGE_PLUGINS[options.storage])
        try:
            self.writer.open()
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
        return {t: types for t, types in graph.items()
                if t not in self.subscriptions and t not in self.skipped and not is_hidden(t)
                and not (self._exclude and self._exclude.search(t))}

    def discover(self) -> list[str]:
        """Subscribe to requested topics that appeared in the graph; the topics newly subscribed."""
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

    def _subscribe(self, topic: str, types: list[str]) -> str | None:
        """Subscribe raw to ``topic`` and register it in the bag; why not, when it cannot be recorded."""
        if len(types) != 1:
            return f'it carries several types ({", ".join(types)})'
        msgtype = types[0]
        if msgtype not in TYPESTORE.types:
            return f'type {msgtype} is unknown to the Jazzy type store (no message definition to store)'
        try:
            msg_class = import_message_type(msgtype)
        except MessageTypeError as exc:
            return str(exc)
        offered = [rosbags_qos(info.qos_profile) for info in self.node.get_publishers_info_by_topic(topic)]
        qos = adapted_qos(self.node, topic, self.options.qos_depth, self.options.reliability, self.options.durability)
        connection = self.writer.add_connection(topic, msgtype, typestore=TYPESTORE, offered_qos_profiles=offered)
        self.subscriptions[topic] = self.node.create_subscription(
            msg_class, topic, self._callback(topic, connection), qos, raw=True)
        self.counts[topic] = 0
        if self.on_subscribe is not None:
            self.on_subscribe(topic, msgtype, qos)
        return None

    def _callback(self, topic: str, connection: Connection) -> Callable[[bytes, dict], None]:
        """The subscription callback writing ``topic``'s bytes with their receive time."""
        def on_message(data: bytes, info: dict) -> None:
            if self.done or self._closed:
                return
            stamp = info.get('received_timestamp') or time.time_ns()
            self.writer.write(connection, stamp, data)
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


def record_until(recorder: BagRecorder, executor: Executor, stop: threading.Event, duration: float | None = None,
                 idle_timeout: float | None = None, status: StatusLine | None = None) -> str:
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
        if idle_timeout is not None and recorder.last_receive is not None \
                and now - recorder.last_receive >= idle_timeout:
            return f'no message for {idle_timeout:g} s'
        if now >= next_look and (recorder.options.all_topics or recorder.missing):
            recorder.discover()
            period = ALL_TOPICS_PERIOD if recorder.options.all_topics else DISCOVERY_PERIOD
            next_look = now + period
        executor.spin_once(timeout_sec=0.05)
        if status is not None:
            status.show(f'recording: {recorder.count} messages on {len(recorder.subscriptions)} topics, '
                        f'{now - start:.1f} s')


# ----------------------------------------------------------------------------- command line

def _positive(text: str) -> float:
    """argparse type: a number > 0."""
    value = float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f'must be positive, not {text}')
    return value


def _not_negative(text: str) -> float:
    """argparse type: a number >= 0."""
    value = float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'must not be negative, not {text}')
    return value


def _count(text: str) -> int:
    """argparse type: an integer >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be at least 1, not {text}')
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The info, play and record sub-commands and their options."""
    sub = parser.add_subparsers(dest='bag_command', metavar='{info,play,record}')
    sub.required = True

    info = sub.add_parser('info', help='show storage, duration, time span and per-topic counts of a bag',
                          description='Show what a rosbag2 holds, like `ros2 bag info`.')
    info.add_argument('bag', type=Path, help='bag directory (or a single .mcap/.db3 file)')
    info.set_defaults(_bag_run=run_info)

    play = sub.add_parser('play', help='publish the messages of a bag with the recorded timing',
                          description='Publish the recorded serialized messages of a bag over DDS.')
    play.add_argument('bag', type=Path, help='bag directory (or a single .mcap/.db3 file)')
    play.add_argument('--rate', '-r', type=_not_negative, default=1.0,
                      help='playback speed factor (default 1; 0 = as fast as possible)')
    play.add_argument('--max-speed', action='store_true', help='publish as fast as possible (same as --rate 0)')
    play.add_argument('--loop', '-l', action='store_true', help='start again at the end, until interrupted')
    play.add_argument('--start-offset', type=_not_negative, default=0.0, metavar='SECONDS',
                      help='start this many seconds into the bag')
    play.add_argument('--topics', nargs='+', metavar='TOPIC', help='play only these topics')
    play.add_argument('--remap', action='append', default=[], metavar='OLD:=NEW',
                      help='publish topic OLD of the bag on NEW (repeatable)')
    play.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                      help='before playing, wait until every topic has at least N matched subscribers')
    play.add_argument('--wait-timeout', type=_positive, default=30.0, metavar='SECONDS',
                      help='give up waiting for subscribers after this long (default 30)')
    play.add_argument('--qos', choices=sorted(RELIABILITY), default='reliable', help='publisher reliability')
    play.add_argument('--qos-depth', type=_count, default=100, help='publisher history depth (default 100)')
    play.add_argument('--durability', choices=sorted(DURABILITY), default='volatile', help='publisher durability')
    play.add_argument('--progress', action='store_true', help='show progress even when stderr is not a terminal')
    play.set_defaults(_bag_run=run_play)

    record = sub.add_parser('record', help='record topics into a bag (mcap, as received on the wire)',
                            description='Record the serialized messages of topics into a new rosbag2.')
    record.add_argument('topics', nargs='*', metavar='TOPIC', help='topics to record')
    record.add_argument('--all', '-a', action='store_true', help='record every topic, including ones appearing later')
    record.add_argument('--exclude', metavar='REGEX', help='with --all, leave out topics matching REGEX')
    record.add_argument('-o', '--output', type=Path, required=True, help='bag directory to create (must not exist)')
    record.add_argument('--storage', choices=sorted(STORAGE_PLUGINS), default='mcap', help='storage format')
    record.add_argument('--max-messages', type=_count, metavar='N', help='stop after N messages in all')
    record.add_argument('--duration', type=_positive, metavar='SECONDS', help='stop after this long')
    record.add_argument('--idle-timeout', type=_positive, metavar='SECONDS',
                        help='stop when no message arrived for this long (once one did)')
    record.add_argument('--qos', choices=['auto'] + sorted(RELIABILITY), default='auto',
                        help='subscription reliability (auto: reliable when every publisher is)')
    record.add_argument('--qos-depth', type=_count, default=100, help='subscription history depth (default 100)')
    record.add_argument('--progress', action='store_true', help='show a status line even when stderr is not a terminal')
    record.set_defaults(_bag_run=run_record)


def run(args: argparse.Namespace) -> int:
    """Run the chosen sub-command; bag and type problems become one-line CLI errors."""
    from memo_ros.tools.cli import CliError
    try:
        return args._bag_run(args)
    except (BagError, MessageTypeError) as exc:
        raise CliError(str(exc)) from None


def run_info(args: argparse.Namespace) -> int:
    """`bag info`: print the summary of a bag."""
    print(format_summary(bag_summary(args.bag)))
    return 0


def _progress_enabled(args: argparse.Namespace) -> bool:
    """Status lines only on a terminal, unless --progress asks for them."""
    return bool(args.progress or sys.stderr.isatty())


def run_play(args: argparse.Namespace) -> int:
    """`bag play`: publish a bag until it ends (or forever with --loop) or a signal stops it."""
    from memo_ros.tools.cli import CliError
    options = PlayOptions(
        rate=0.0 if args.max_speed else args.rate, loop=args.loop, start_offset=args.start_offset,
        topics=args.topics, remap=parse_remaps(args.remap), reliability=args.qos, durability=args.durability,
        qos_depth=args.qos_depth, wait_for_subscribers=args.wait_for_subscribers, wait_timeout=args.wait_timeout)
    status = StatusLine(_progress_enabled(args))
    # one process publishing every camera's images needs more than Fast DDS's 512 KiB shared-memory segment
    with tempfile.TemporaryDirectory(prefix='memo_bag_play_') as tmp, player_segment(PLAYER_SEGMENT_BYTES, tmp), \
            ros_session('memo_ros_bag_player') as (node, _executor), stop_on_signals() as stop:
        with BagPlayer(node, args.bag, options) as player:
            duration = max(player.end_ns - player.start_ns, 0) / 1e9

            def show(item: PlayedMessage) -> None:
                status.show(f'playing: {(item.log_time_ns - player.start_ns) / 1e9:7.2f} / {duration:.2f} s, '
                            f'{item.index + 1} messages')

            player.after_publish = show
            print(f'playing {sum(c.msgcount for c in player.connections)} messages on {len(player.topics)} '
                  f'topics from {args.bag}', file=sys.stderr)
            missing = player.wait_for_subscribers(stop)
            if missing and not stop.is_set():
                raise CliError(f'fewer than {options.wait_for_subscribers} subscriber(s) after '
                               f'{options.wait_timeout:g} s on: {", ".join(missing)}')
            published = player.play(stop)
            status.close()
            if not player.flush():
                print('bag play: some subscribers did not acknowledge every message', file=sys.stderr)
    print(f'{"stopped after" if stop.is_set() else "done:"} {published} messages published', file=sys.stderr)
    return 0


def run_record(args: argparse.Namespace) -> int:
    """`bag record`: record until a signal or a stop condition, then close the bag properly."""
    from memo_ros.tools.cli import CliError
    if not args.topics and not args.all:
        raise CliError('name the topics to record, or use --all')
    if args.topics and args.all:
        raise CliError('give either topics or --all, not both')
    if args.exclude:
        try:
            re.compile(args.exclude)
        except re.error as exc:
            raise CliError(f'bad --exclude regex: {exc}') from None
    if args.output.exists():
        raise CliError(f'output {args.output} exists already; choose another name or remove it')
    options = RecordOptions(topics=args.topics, all_topics=args.all, exclude=args.exclude, storage=args.storage,
                            reliability=args.qos, qos_depth=args.qos_depth, max_messages=args.max_messages)

    def subscribed(topic: str, msgtype: str, qos: QoSProfile) -> None:
        print(f'recording {topic} ({msgtype}, {qos.reliability.name.lower()})', file=sys.stderr)

    def skipped(topic: str, reason: str) -> None:
        print(f'bag record: not recording {topic}: {reason}', file=sys.stderr)

    status = StatusLine(_progress_enabled(args))
    with ros_session('memo_ros_bag_recorder') as (node, executor), stop_on_signals() as stop:
        with BagRecorder(node, args.output, options, subscribed, skipped) as recorder:
            reason = record_until(recorder, executor, stop, args.duration, args.idle_timeout, status)
            status.close()
    per_topic = ', '.join(f'{t}: {n}' for t, n in sorted(recorder.counts.items()))
    print(f'stopped ({reason}): {recorder.count} messages written to {args.output}'
          + (f' ({per_topic})' if per_topic else ''), file=sys.stderr)
    if recorder.missing:
        print(f'bag record: never saw {", ".join(recorder.missing)}', file=sys.stderr)
    return 0
