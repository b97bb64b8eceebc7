"""The one ``main`` every node shares: init, build, spin, and a one-line error for a refused configuration."""
from __future__ import annotations

import sys
from typing import Callable

import cv2
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node


def run_node(name: str, make_node: Callable[[], Node], args: list[str] | None = None) -> int:
    """Spin the node ``make_node`` builds until Ctrl-C or shutdown; exit 2 with one line if it refuses to start.

    A node class with ``executor_threads`` > 1 spins on a multi-threaded executor (its callback groups say
    what may run in parallel)."""
    cv2.setNumThreads(1)            # one process per camera and stage share the cores (see memo_ros.nodes)
    rclpy.init(args=args if args is not None else sys.argv)
    try:
        node = make_node()
    except (ValueError, KeyError, ParameterException) as exc:
        print(f'{name}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    threads = getattr(node, 'executor_threads', 1)
    executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()
    try:
        rclpy.spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
