"""The graph benchmark's processes: start and stop the launcher; CPU and RSS per node."""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from memo_ros.tools.proc_stats import (
    children,
    cpu_seconds,
    log_tail,
    peak_rss_mb,
    rss_mb,
    stop_process,
)

GRAPH_TIMEOUT = 90.0  # s for the nodes to start, match and report on /diagnostics
RSS_PERIOD = 2.0  # s between resident-memory samples of every process


STOP_TIMEOUT = 15.0  # s for the launcher to stop its nodes after SIGINT


def node_label(command: list[str]) -> str:
    """'cam_front/contour_node', 'selector_node', ....

    The launcher's label of a node's command line.
    """
    module = command[command.index('-m') + 1] if '-m' in command else Path(command[0]).name
    name = module.rsplit('.', 1)[-1]
    namespace = next(
        (w.split(':=', 1)[1].strip('/') for w in command if w.startswith('__ns:=')), ''
    )
    return f'{namespace}/{name}' if namespace else name


def start_graph(studio_file: Path, env: dict, log: Path) -> subprocess.Popen:
    """Start ``memo-ros launch STUDIO``, its output to ``log``.

    Images are best-effort, as for live cameras.
    """
    with open(log, 'w') as out:
        return subprocess.Popen(
            [sys.executable, '-m', 'memo_ros.tools.cli', 'launch', str(studio_file)],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )


def wait_for_nodes(launch: subprocess.Popen, expected: int, log: Path) -> dict[int, str]:
    """Return the launcher's node processes (pid -> label), once all ``expected`` run."""
    from memo_ros.tools.cli import CliError

    deadline = time.monotonic() + GRAPH_TIMEOUT
    while True:
        # a child just forked still shows the launcher's command line until it execs its node: wait
        # for that
        nodes = {
            pid: node_label(command)
            for pid, command in children(launch.pid).items()
            if any('memo_ros.nodes.' in word for word in command)
        }
        if len(nodes) >= expected:
            return nodes
        if launch.poll() is not None:
            raise CliError(f'the graph stopped before it was up: {log_tail(log)}')
        if time.monotonic() > deadline:
            raise CliError(f'{len(nodes)} of {expected} nodes started within {GRAPH_TIMEOUT:g} s')
        time.sleep(0.1)


def stop_graph(launch: subprocess.Popen, nodes: dict[int, str]) -> None:
    """SIGINT to the launcher (it stops its nodes).

    Kill it, then any node of it left, on a timeout.
    """
    nodes = nodes or (
        children(launch.pid) if launch.poll() is None else {}
    )  # stopped while starting
    stop_process(launch, STOP_TIMEOUT)
    for pid in nodes:
        try:
            with open(f'/proc/{pid}/cmdline', 'rb') as f:
                still_ours = b'memo_ros.nodes.' in f.read()
            if still_ours:
                os.kill(pid, signal.SIGKILL)
        except (OSError, ProcessLookupError):
            pass  # ended, as it should have


def cpu_snapshot(pids: dict[int, str]) -> tuple[float, dict[int, float]]:
    """(monotonic time, CPU seconds per pid) now; a process that ended is left out."""
    now = time.monotonic()
    cpu = {}
    for pid in pids:
        try:
            cpu[pid] = cpu_seconds(pid)
        except OSError:
            pass
    return now, cpu


def rss_of(pids: dict[int, str]) -> dict[int, float | None]:
    """Return each process's resident memory, MB (None once it has ended)."""
    out = {}
    for pid in pids:
        try:
            out[pid] = rss_mb(pid)
        except OSError:
            out[pid] = None
    return out


def memory_growth(
    pids: dict[int, str], samples: list[tuple[int, dict]], warmup: int
) -> list[dict]:
    """Per process.

    Resident memory once warm (the first sample after the warm-up frames and a tenth of the run),
    at the end, and the growth between them, MB.
    """
    rows = []
    total = samples[-1][0] if samples else 0
    warm = [s for s in samples if s[0] >= max(warmup, total // 10)] or samples
    for pid, label in pids.items():
        start = next((mb[pid] for _, mb in warm if mb.get(pid) is not None), None)
        end = next((mb[pid] for _, mb in reversed(samples) if mb.get(pid) is not None), None)
        rows.append(
            {
                'process': label,
                'rss_warm_mb': start,
                'rss_end_mb': end,
                'growth_mb': end - start if start is not None and end is not None else None,
                'samples': len(samples),
            }
        )
    return rows


def peak_rss_of(pid: int) -> float | None:
    """Return a process's peak resident memory (VmHWM), MB, or None once it has ended."""
    try:
        return peak_rss_mb(pid)
    except OSError:
        return None


def cpu_between(start: tuple | None, end: tuple | None, pid: int) -> tuple[float, float] | None:
    """(CPU seconds, wall seconds) of ``pid`` between two snapshots (None when not in both)."""
    if start and end and pid in start[1] and pid in end[1] and end[0] > start[0]:
        return end[1][pid] - start[1][pid], end[0] - start[0]
    return None
