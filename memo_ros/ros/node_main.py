"""The one ``main`` every node shares.

Init, build, spin, and a one-line error for a refused configuration.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from typing import Callable

import cv2
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from memo_ros.ros.dds import use_node_dds_profile

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
SPIN_PERIOD_S = 0.1  # how soon a stop signal is noticed: the executor's longest wait
EXECUTOR_ENV = 'MEMO_ROS_EXECUTOR'  # single_threaded (default) or events (rclpy 7.1's, opt-in)


M_MMAP_THRESHOLD = -3  # glibc mallopt parameter (malloc.h)
MMAP_THRESHOLD_BYTES = 8 << 20


def release_large_buffers() -> bool:
    """Have glibc give every buffer of 8 MiB or more back to the system when it is freed.

    glibc raises its mmap threshold to the largest buffer freed (up to 32 MiB): after one 4k
    image, image-sized buffers came from the heap and stayed resident.  A fixed threshold keeps
    them mapped on their own; a VGA frame's arrays (at most 3.7 MB) stay on the heap, so no
    frame pays for a mapping.  Returns whether it applied (glibc only).
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library('c')
    if not name:
        return False
    try:
        return bool(ctypes.CDLL(name).mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    except (OSError, AttributeError):  # not glibc
        return False


def make_executor() -> Executor:
    """Return rclpy's SingleThreadedExecutor, or its EventsExecutor with MEMO_ROS_EXECUTOR=events.

    The single-threaded executor rebuilds its wait set in Python at every spin, over every
    subscription, timer, service and QoS event handler of the node: under cProfile that was half
    of the tracker node's intake thread. The events executor waits in C++ (rclpy 7.1's
    ``rclpy.experimental``) and halves that, but with it the fresh-clone suite lost a message
    twice in two runs (a replay's frame report, a selector's assignment), so it is opt-in; an
    rclpy without it gets the single-threaded one.
    """
    if os.environ.get(EXECUTOR_ENV, 'single_threaded') == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # an rclpy without it
            pass
        else:
            return EventsExecutor()
    return SingleThreadedExecutor()


def run_node(name: str, make_node: Callable[[], Node], args: list[str] | None = None) -> int:
    """Spin the node ``make_node`` builds until SIGINT, SIGTERM or shutdown; return the exit code.

    0 after a stop signal or shutdown; 2 with one line if the node refuses to start; 1 if a
    thread of its own failed (it sets ``failure`` and shuts the context down).  A stop signal
    only sets a flag (rclpy's handlers would invalidate the context under a thread still
    publishing, and a second Ctrl-C would raise KeyboardInterrupt anywhere): spinning stops
    within SPIN_PERIOD_S, the node is destroyed (its own threads finish) while further
    signals are merely noted, then rclpy shuts down.

    One executor thread per node: rclpy's multi-threaded executor left ready callbacks waiting
    for up to seconds on these 2-core machines; a node that must not block its intake runs its
    work on its own thread.
    """
    stop = threading.Event()
    for sig in STOP_SIGNALS:  # a signal never raises, not even in the node's shutdown
        signal.signal(sig, lambda signum, frame: stop.set())
    cv2.setNumThreads(1)  # one process per camera and stage share the cores (see memo_ros.nodes)
    use_node_dds_profile()  # an oversized message must not stay resident in DDS's buffers
    release_large_buffers()
    rclpy.init(
        args=args if args is not None else sys.argv,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    try:
        node = make_node()
    except (ValueError, KeyError, ParameterException) as exc:
        print(f'{name}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = make_executor()
    executor.add_node(node)
    try:
        while not stop.is_set() and node.context.ok():
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    except ExternalShutdownException:
        pass
    finally:
        if stop.is_set():
            node.get_logger().info('stopping on a signal')
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        # ignored from here on: Python's finalisation would restore the default actions, and a
        # late signal (ros2 launch's second Ctrl-C) would kill the exiting process
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
    failure = getattr(node, 'failure', None)
    if failure is not None:
        print(
            f'{name}: error: {" ".join(str(failure).split()) or type(failure).__name__}',
            file=sys.stderr,
        )
        return 1
    return 0
