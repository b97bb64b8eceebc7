"""`bag info`: what a rosbag2 holds (storage, duration, per-topic counts), like `ros2 bag info`."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import yaml

from memo_ros.ros.bagio import open_bag


def storage_of(path: Path) -> tuple[str, list[Path]]:
    """Storage id ('mcap' or 'sqlite3') and data files of a bag directory or storage file."""
    if path.is_dir():
        metadata = yaml.safe_load((path / 'metadata.yaml').read_text())[
            'rosbag2_bagfile_information'
        ]
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
        """Return the time from the first to the last message, ns."""
        return self.end_ns - self.start_ns


def bag_summary(path: str | Path) -> BagSummary:
    """Storage, time span, message count and per-topic type and count of a bag."""
    path = Path(path)
    reader = open_bag(path)
    try:
        storage, files = storage_of(path)
        topics = [
            TopicSummary(
                name,
                info.msgtype or ', '.join(sorted({c.msgtype for c in info.connections})),
                info.msgcount,
                info.connections[0].ext.serialization_format if info.connections else '',
            )
            for name, info in reader.topics.items()
        ]
        count = reader.message_count
        start = reader.start_time if count else 0
        end = reader.end_time - 1 if count else 0
        return BagSummary(
            path,
            storage,
            files,
            sum(f.stat().st_size for f in files if f.exists()),
            reader.ros_distro or '',
            start,
            end,
            count,
            topics,
        )
    finally:
        reader.close()


def format_stamp(stamp_ns: int) -> str:
    """'2026-01-01T00:00:00.000000000Z (1767225600.000000000)': UTC ISO time and the raw stamp."""
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    iso = datetime.fromtimestamp(sec, tz=timezone.utc).strftime('%Y-%m-%dT%H:%M:%S')
    return f'{iso}.{nsec:09d}Z ({sec}.{nsec:09d})'


def format_size(size: int) -> str:
    """Return a byte count for humans (KiB, MiB, ...)."""
    value = float(size)
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if value < 1024 or unit == 'GiB':
            return f'{value:.0f} {unit}' if unit == 'B' else f'{value:.1f} {unit}'
        value /= 1024
    return f'{size} B'


def format_summary(summary: BagSummary) -> str:
    """Return the text of ``bag info``, laid out like ``ros2 bag info``."""
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
        lines.append(
            f'  {t.topic:<{width}} | Type: {t.msgtype:<{type_width}} | Count: {t.count:>7} | '
            f'Serialization Format: {t.serialization_format}'
        )
    return '\n'.join(lines)


def run_info(args: argparse.Namespace) -> int:
    """`bag info`: print the summary of a bag."""
    print(format_summary(bag_summary(args.bag)))
    return 0
