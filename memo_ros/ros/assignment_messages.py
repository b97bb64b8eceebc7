"""The camera assignment on ``/memo/camera_assignment`` as a diagnostic_msgs/DiagnosticArray.

One DiagnosticStatus per part, in part order: ``name`` = the part, ``level``
OK when some camera sees it and WARN when it is unobserved, ``message`` = the
selected cameras best first, comma-separated (or ``unobserved``), and
``values`` = ``<cam>.vi``, ``<cam>.observability``, ``<cam>.selected``,
``<cam>.alive`` per camera, then ``mode``.  ``ros2 topic echo`` shows it as
plain text; ``memo-ros echo`` prints it as a part x camera table.
"""

from __future__ import annotations

import math

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np

from memo_ros.core.geometry.body import PART_NAMES
from memo_ros.core.multiview.selection import Assignment
from memo_ros.ros.body_messages import WORLD, stamp_from_ns

HARDWARE_ID = 'memo_camera_assignment'
UNOBSERVED = 'unobserved'
FIELDS = ('vi', 'observability', 'selected', 'alive')


def _number(value: float, digits: int) -> str:
    return 'nan' if not math.isfinite(value) else f'{value:.{digits}f}'


def _flag(value: bool) -> str:
    return 'true' if value else 'false'


def assignment_to_message(assignment: Assignment, stamp: Time | int) -> DiagnosticArray:
    """Return the assignment of frame ``stamp`` (builtin_interfaces/Time or ns) in ``world``."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp if isinstance(stamp, Time) else stamp_from_ns(int(stamp))
    msg.header.frame_id = WORLD
    for i in range(assignment.selected.shape[0]):
        status = DiagnosticStatus(name=PART_NAMES[i], hardware_id=HARDWARE_ID)
        status.level = DiagnosticStatus.OK if assignment.observed[i] else DiagnosticStatus.WARN
        status.message = ', '.join(assignment.cameras_for(i)) or UNOBSERVED
        values = []
        for k, cam in enumerate(assignment.cameras):
            values += [
                KeyValue(key=f'{cam}.vi', value=_number(assignment.vi[i, k], 3)),
                KeyValue(
                    key=f'{cam}.observability', value=_number(assignment.observability[i, k], 2)
                ),
                KeyValue(key=f'{cam}.selected', value=_flag(assignment.selected[i, k])),
                KeyValue(key=f'{cam}.alive', value=_flag(assignment.alive[k])),
            ]
        values.append(KeyValue(key='mode', value=assignment.mode))
        status.values = values
        msg.status.append(status)
    return msg


def is_assignment_message(msg) -> bool:
    """Return True for a DiagnosticArray in this module's layout.

    One status per part, with a ``mode`` value.
    """
    if not isinstance(msg, DiagnosticArray) or len(msg.status) != len(PART_NAMES):
        return False
    return all(s.name == p for s, p in zip(msg.status, PART_NAMES)) and any(
        kv.key == 'mode' for kv in msg.status[0].values
    )


def assignment_from_message(msg: DiagnosticArray) -> Assignment:
    """Return the Assignment a message carries; ValueError when it is not in this layout."""
    if not is_assignment_message(msg):
        raise ValueError(
            'not a camera assignment: expected one DiagnosticStatus per part in part order '
            'with a "mode" value'
        )
    cameras: list[str] = []
    for kv in msg.status[0].values:
        cam, _, key = kv.key.rpartition('.')
        if key == 'vi' and cam:
            cameras.append(cam)
    n_parts, n_cams = len(msg.status), len(cameras)
    vi = np.full((n_parts, n_cams), np.nan)
    obs = np.full((n_parts, n_cams), np.nan)
    selected = np.zeros((n_parts, n_cams), bool)
    alive = np.zeros(n_cams, bool)
    rank = np.full((n_parts, n_cams), -1, int)
    index = {c: k for k, c in enumerate(cameras)}
    mode = ''
    for i, status in enumerate(msg.status):
        for kv in status.values:
            if kv.key == 'mode':
                mode = kv.value
                continue
            cam, _, key = kv.key.rpartition('.')
            if cam not in index:
                raise ValueError(
                    f'part {status.name}: value {kv.key!r} names a camera missing from the first '
                    'part'
                )
            k = index[cam]
            if key == 'vi':
                vi[i, k] = float(kv.value)
            elif key == 'observability':
                obs[i, k] = float(kv.value)
            elif key == 'selected':
                selected[i, k] = kv.value == 'true'
            elif key == 'alive':
                alive[k] = kv.value == 'true'
        if status.message != UNOBSERVED:
            for r, cam in enumerate(c.strip() for c in status.message.split(',') if c.strip()):
                if cam in index:
                    rank[i, index[cam]] = r
    observed = np.array([s.level == DiagnosticStatus.OK for s in msg.status], bool)
    return Assignment(cameras, vi, obs, selected, observed, alive, mode, rank)


def assignment_rows(msg: DiagnosticArray) -> list[dict]:
    """One row per (part, camera).

    Part, observed, camera, alive, vi, observability, selected, rank (1 = best).
    """
    a = assignment_from_message(msg)
    rows = []
    for i, part in enumerate(PART_NAMES):
        for k, cam in enumerate(a.cameras):
            rows.append(
                {
                    'part': part,
                    'observed': bool(a.observed[i]),
                    'camera': cam,
                    'alive': bool(a.alive[k]),
                    'vi': float(a.vi[i, k]),
                    'observability': float(a.observability[i, k]),
                    'selected': bool(a.selected[i, k]),
                    'rank': int(a.rank[i, k]) + 1 if a.rank[i, k] >= 0 else 0,
                }
            )
    return rows


def assignment_table(msg: DiagnosticArray) -> list[str]:
    """Return the message as text lines.

    a header, then a part x camera table (rank 1 = the best selected camera).
    """
    a = assignment_from_message(msg)
    stamp = msg.header.stamp
    lines = [
        f'camera assignment  stamp {stamp.sec}.{stamp.nanosec:09d}  frame_id '
        f'{msg.header.frame_id}  '
        f'mode {a.mode}',
        f'{"part":<12} {"camera":<12} {"alive":<5} {"vi":>6} {"observability":>13} '
        f'{"selected":>8}',
    ]
    for i, part in enumerate(PART_NAMES):
        label = part if a.observed[i] else f'{part} !'
        for k, cam in enumerate(a.cameras):
            chosen = f'#{a.rank[i, k] + 1}' if a.selected[i, k] else '-'
            lines.append(
                f'{label if k == 0 else "":<12} {cam:<12} {"yes" if a.alive[k] else "NO":<5} '
                f'{_number(a.vi[i, k], 3):>6} {_number(a.observability[i, k], 2):>13} {chosen:>8}'
            )
    lines.append(
        '(#n: selected, n-th by observability; "!": unobserved, the tracker only predicts it)'
    )
    return lines
