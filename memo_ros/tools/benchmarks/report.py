"""What every benchmark report shares.

The machine it ran on, timing and percentiles, the command line.
"""

from __future__ import annotations

import os
import platform
import time
from typing import Callable

import numpy as np


def with_command(show):
    """Return a report printer that first prints the command line that produced the report."""

    def printer(report: dict) -> None:
        print(f'command  {report["command"]}')
        show(report)

    return printer


def machine() -> dict:
    """Where the figures were measured: CPUs, Python, numpy and OpenCV versions."""
    import cv2

    usable = len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count()
    return {
        'cpu_count': os.cpu_count(),
        'cpus_usable': usable,
        'processor': platform.processor() or platform.machine(),
        'python': platform.python_version(),
        'numpy': np.__version__,
        'opencv': cv2.__version__,
        'platform': platform.platform(),
    }


def time_ms(call: Callable[[], object], repeat: int) -> np.ndarray:
    """Wall-clock milliseconds of ``repeat`` calls, after one untimed warm-up call (ray caches)."""
    call()
    times = np.empty(repeat)
    for k in range(repeat):
        start = time.perf_counter()
        call()
        times[k] = time.perf_counter() - start
    return 1000.0 * times


def percentiles(values_ms: list[float]) -> dict | None:
    """p50, p99, mean and max of latencies (ms), with their count; None without any."""
    if not values_ms:
        return None
    v = np.asarray(values_ms)
    return {
        'n': int(v.size),
        'p50': float(np.percentile(v, 50)),
        'p99': float(np.percentile(v, 99)),
        'mean': float(v.mean()),
        'max': float(v.max()),
    }
