"""`memo-ros launch`.

One contour_node per camera as processes; all stop together; a dead node is restarted, one
that keeps dying stops the graph.
"""

from __future__ import annotations

import os
import queue
import re
import signal
import threading
import time

from memo_ros.core.formats.studio import Studio, load_studio, studio_path
from memo_ros.ros.dds import ros_session
from memo_ros.tools.launch import graph_commands


def _wait_for_nodes(ros_env, topics, timeout=20.0):
    with ros_session('launch_probe', ros_env.domain_id) as (node, _):
        deadline = time.monotonic() + timeout
        while not all(node.count_publishers(t) for t in topics):
            assert time.monotonic() < deadline, f'nodes did not come up: {topics}'
            time.sleep(0.2)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _started_pids(output: str) -> list[int]:
    return [int(p) for p in re.findall(r'started \S+ \(pid (\d+)[,)]', output)]


def test_ctrl_c_stops_every_node_and_exits_zero(ros_env):
    studio = load_studio('studio_orthogonal')
    cameras = studio.camera_names
    launcher = ros_env.start('launch', 'studio_orthogonal')
    _wait_for_nodes(ros_env, [f'/{c}/contours' for c in cameras])
    launcher.send_signal(signal.SIGINT)
    out, _ = launcher.communicate(timeout=30)
    assert launcher.returncode == 0, out
    pids = _started_pids(out)
    labels = [n.label for n in graph_commands(studio, studio_path('studio_orthogonal'))]
    assert 'selector_node' in labels  # the multi-camera graph selects cameras per part
    assert len(pids) == len(labels) and not any(_alive(p) for p in pids)
    assert 'stopping on request' in out


class _Lines:
    """Collect a process's output lines on a thread, to wait for one with a timeout."""

    def __init__(self, process) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, args=(process,), daemon=True).start()

    def _read(self, process) -> None:
        for line in process.stdout:
            self.lines.put(line)

    def wait_for(self, pattern: str, timeout: float) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                continue
            self.seen.append(line)
            if re.search(pattern, line):
                return line
        raise AssertionError(
            f'no line matching {pattern!r} in {timeout} s:\n' + ''.join(self.seen)
        )


def _diagnostics_value(ros_env, name: str, key: str, timeout: float = 10.0) -> str | None:
    """Return ``key`` of the /diagnostics status whose name contains ``name`` (None: not seen)."""
    from diagnostic_msgs.msg import DiagnosticArray

    found: dict[str, str] = {}

    def on_message(msg) -> None:
        for status in msg.status:
            if name in status.name:
                found.update({v.key: v.value for v in status.values})

    with ros_session('launch_diagnostics_probe', ros_env.domain_id) as (node, executor):
        node.create_subscription(DiagnosticArray, '/diagnostics', on_message, 50)
        deadline = time.monotonic() + timeout
        while key not in found and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    return found.get(key)


def test_a_killed_node_is_back_within_five_seconds_and_its_restart_shows(ros_env):
    launcher = ros_env.start('launch', 'street')
    lines = _Lines(launcher)
    first = lines.wait_for(r'started \S+/contour_node \(pid', 30)
    _wait_for_nodes(ros_env, ['/cam_street/contours'])
    pid = _started_pids(first)[0]
    killed = time.monotonic()
    os.kill(pid, signal.SIGKILL)
    lines.wait_for(r'cam_street/contour_node was killed by SIGKILL; restarting it in 0.5 s', 5)
    again = lines.wait_for(r'started cam_street/contour_node \(pid \d+, restart 1\)', 5)
    assert _started_pids(again)[0] != pid
    assert _diagnostics_value(ros_env, 'contour_node', 'restarts') == '1'
    assert time.monotonic() - killed < 15.0  # the node was back (publishing diagnostics)
    assert launcher.poll() is None  # the graph goes on
    launcher.send_signal(signal.SIGINT)
    launcher.wait(timeout=30)
    assert launcher.returncode == 0


def test_a_node_that_keeps_dying_stops_the_graph_with_its_reason(ros_env):
    launcher = ros_env.start('launch', 'street', '--max-restarts', '1')
    lines = _Lines(launcher)
    for _ in range(2):
        started = lines.wait_for(r'started cam_street/contour_node \(pid', 30)
        time.sleep(1.0)
        os.kill(_started_pids(started)[0], signal.SIGKILL)
    line = lines.wait_for('stopping the others', 30)
    launcher.wait(timeout=30)
    assert launcher.returncode != 0
    assert 'cam_street/contour_node was killed by SIGKILL; it died 2 times' in line


def test_unknown_studio_is_one_line(ros_env):
    result = ros_env.run('launch', 'no_such_studio')
    assert result.returncode != 0 and 'Traceback' not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_ros2_launch_file_compiles_and_names_the_shipped_executable():
    from conftest import ROOT

    source = (ROOT / 'launch' / 'memo.launch.py').read_text()
    compile(source, 'memo.launch.py', 'exec')
    setup = (ROOT / 'setup.py').read_text()
    assert (
        "executable='contour_node'" in source
        and "'contour_node = memo_ros.nodes.contour_node:main'" in setup
    )
    assert (
        "executable='selector_node'" in source
        and "'selector_node = memo_ros.nodes.selector_node:main'" in setup
    )


def test_roles_split_the_graph_between_camera_hosts_and_a_tracking_host():
    studio = Studio.load(studio_path('studio_orthogonal'))
    path = studio_path('studio_orthogonal')
    everything = [n.label for n in graph_commands(studio, path)]
    cameras = [n.label for n in graph_commands(studio, path, role='cameras')]
    tracking = [n.label for n in graph_commands(studio, path, role='tracking')]
    assert cameras == [f'{c}/contour_node' for c in studio.camera_names]
    assert tracking == ['selector_node', 'tracker_node']
    assert sorted(cameras + tracking) == sorted(everything)
