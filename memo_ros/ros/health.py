"""Per-node bookkeeping of frames in, processed and dropped (with reasons).

Published on /diagnostics.

Every frame a node does not process is counted under a reason and logged with a throttled one-line
warning, so nothing is dropped silently.  An unexpected exception in a callback is caught at the
node's edge (:meth:`NodeHealth.guard`), counted as ``internal_error`` with its first traceback
logged, and the node goes on.
"""

from __future__ import annotations

from collections import Counter
import os
import threading
import time
import traceback
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

LOG_THROTTLE_S = 2.0
# topics every rclpy node has, left out of the matched counts
INFRASTRUCTURE_TOPICS = frozenset({'/rosout', '/parameter_events', '/diagnostics'})
INTERNAL_ERROR = (
    'internal_error'  # the reason an unexpected exception in a callback is counted under
)


class NodeHealth:
    """Counters, the last problem, and a periodic DiagnosticArray for one node.

    Safe to use from a node's own threads as well as its callbacks.
    """

    def __init__(self, node: Node, name: str, hardware_id: str = '', period: float = 1.0) -> None:
        self._node = node
        self._name = name
        self._hardware_id = hardware_id
        self.counters: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.values: dict[str, str] = {}
        self._problem = ''
        self._level = DiagnosticStatus.OK
        self._lock = threading.Lock()
        self._failed: set[str] = set()  # callbacks whose traceback was logged
        self._logged: dict[str, float] = {}  # reason -> monotonic time of its last log line
        restarts = os.environ.get('MEMO_ROS_RESTARTS', '0')  # set by `memo-ros launch`
        if restarts.isdigit() and int(restarts) > 0:
            self.values['restarts'] = restarts
        self._publisher = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._timer = node.create_timer(period, self.guard(self.publish, 'diagnostics timer'))

    def count(self, key: str, n: int = 1) -> None:
        """Add ``n`` to counter ``key`` (frames_in, processed, ...)."""
        with self._lock:
            self.counters[key] += n

    def drop(self, reason: str, message: str) -> None:
        """Count a frame not processed under ``reason``; log ``message``, throttled per reason."""
        with self._lock:
            self.dropped[reason] += 1
            self._problem = f'{reason}: {message}'
            self._level = DiagnosticStatus.WARN
            count = self.dropped[reason]
        if self._due(reason):
            self._node.get_logger().warning(f'{message} [dropped: {reason}, {count} so far]')

    def note(self, reason: str, message: str) -> None:
        """Count an event that is not a drop (a reset, a warm-up) and log it throttled."""
        with self._lock:
            self.counters[reason] += 1
            self._problem = f'{reason}: {message}'
        if self._due(reason):
            self._node.get_logger().info(message)

    def warn(self, reason: str, message: str) -> None:
        """Count an event that needs attention (a reset of learnt state); log it as a warning."""
        with self._lock:
            self.counters[reason] += 1
            self._problem = f'{reason}: {message}'
            self._level = DiagnosticStatus.WARN
        if self._due(reason):
            self._node.get_logger().warning(message)

    def _due(self, reason: str) -> bool:
        """Return whether ``reason`` may log now: once per LOG_THROTTLE_S for each reason.

        Throttled here, not by rclpy's ``throttle_duration_sec``: that throttles per call site (one
        for every reason) and finds its caller on the stack at every call, a tenth of a contour
        node's CPU while images were being lost.
        """
        now = time.monotonic()
        with self._lock:
            last = self._logged.get(reason)
            if last is not None and now - last < LOG_THROTTLE_S:
                return False
            self._logged[reason] = now
            return True

    def internal_error(self, what: str, exc: BaseException) -> None:
        """Count an exception of ``what`` as internal_error; log its first traceback in full."""
        with self._lock:
            first = what not in self._failed
            self._failed.add(what)
        if first:
            trace = ''.join(traceback.format_exception(exc)).rstrip()
            self._node.get_logger().error(f'{what} failed (the node goes on): {exc!r}\n{trace}')
        self.drop(INTERNAL_ERROR, f'{what} failed: {exc!r}')

    def guard(self, callback: Callable, what: str, service: bool = False) -> Callable:
        """Wrap a subscription, service or timer callback: an exception is counted, never raised.

        A ``service`` callback's response (its second argument) is returned, with success false
        and the error as its message when it has those fields.
        """

        def guarded(*args):
            try:
                return callback(*args)
            except Exception as exc:  # noqa: BLE001 - the node's edge: nothing raises out of it
                self.internal_error(what, exc)
                if service:
                    response = args[1]
                    if hasattr(response, 'success'):
                        response.success = False
                    if hasattr(response, 'message'):
                        response.message = f'internal error: {exc!r}'
                    return response
                return None

        return guarded

    def ok(self) -> None:
        """Return a frame went through.

        Clear the warning level (the last problem stays in the values).
        """
        self._level = DiagnosticStatus.OK

    def set(self, key: str, value) -> None:
        """Publish ``key: value`` with the next diagnostics."""
        with self._lock:
            self.values[key] = str(value)

    def status(self) -> DiagnosticStatus:
        """Return the node's current DiagnosticStatus."""
        status = DiagnosticStatus()
        status.level = self._level
        status.name = self._name
        status.hardware_id = self._hardware_id
        with self._lock:
            status.message = 'OK' if self._level == DiagnosticStatus.OK else self._problem
            values = [KeyValue(key=k, value=str(v)) for k, v in sorted(self.counters.items())]
            values += [
                KeyValue(key=f'dropped.{k}', value=str(v)) for k, v in sorted(self.dropped.items())
            ]
            values.append(KeyValue(key='dropped.total', value=str(sum(self.dropped.values()))))
            values += [KeyValue(key=k, value=v) for k, v in sorted(self.values.items())]
            if self._problem:
                values.append(KeyValue(key='last_problem', value=self._problem))
        values += [KeyValue(key=k, value=str(n)) for k, n in self.matched().items()]
        status.values = values
        return status

    def matched(self) -> dict[str, int]:
        """Return the endpoints each of the node's topics is matched with, as DDS sees it here.

        ``subscribers.<topic>`` for an output, ``publishers.<topic>`` for an input: this node's
        own half of each match, which a recorder or player elsewhere cannot see (data sent before
        both halves matched is lost).
        """
        counts = {
            f'subscribers.{p.topic_name}': p.get_subscription_count()
            for p in self._node.publishers
            if p.topic_name not in INFRASTRUCTURE_TOPICS
        }
        counts.update(
            {
                f'publishers.{s.topic_name}': s.get_publisher_count()
                for s in self._node.subscriptions
                if s.topic_name not in INFRASTRUCTURE_TOPICS
            }
        )
        return dict(sorted(counts.items()))

    def publish(self) -> None:
        """Send the status on /diagnostics."""
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        msg.status = [self.status()]
        self._publisher.publish(msg)
