"""The executor every node spins: the single-threaded one unless MEMO_ROS_EXECUTOR asks."""

from __future__ import annotations

import rclpy
from rclpy.executors import SingleThreadedExecutor

from memo_ros.ros.node_main import EXECUTOR_ENV, make_executor


def test_the_classic_executor_by_default_and_the_events_one_when_asked(monkeypatch):
    rclpy.init(args=[])  # a context only: no node, so nothing goes on the network
    try:
        monkeypatch.delenv(EXECUTOR_ENV, raising=False)
        classic = make_executor()
        assert isinstance(classic, SingleThreadedExecutor)
        classic.shutdown()
        monkeypatch.setenv(EXECUTOR_ENV, 'events')
        events = make_executor()
        assert type(events).__name__ == 'EventsExecutor'
        events.shutdown()
    finally:
        rclpy.try_shutdown()
