"""The one ``main`` every node shares: init, build, spin, and a one-line error for a refused configuration."""

from __future__ import annotations

import sys
from typing import Callable

import cv2
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


def run_node(name: str, make_node: Callable[[], Node], args: list[str] | None = None) -> int:
    """Spin the node ``make_node`` builds until Ctrl-C or shutdown; exit 2 with one line if it refuses to start,
    1 if a thread of its own failed (it sets ``failure`` and shuts the context down).

    One executor thread per node: rclpy's multi-threaded executor left ready callbacks waiting for up to
    seconds on these 2-core machines; a node that must not block its intake runs its work on its own thread.
    """
    cv2.setNumThreads(1)  # one process per camera and stage share the cores (see memo_ros.nodes)
    rclpy.init(args=args if args is not None else sys.argv)
    try:
        node = make_node()
    except (ValueError, KeyError, ParameterException) as exc:
        print(f'{name}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node, SingleThreadedExecutor())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    failure = getattr(node, 'failure', None)
    if failure is not None:
        print(
            f'{name}: error: {" ".join(str(failure).split()) or type(failure).__name__}',
            file=sys.stderr,
        )
        return 1
    return 0
