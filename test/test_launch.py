"""`memo-ros launch`.

One contour_node per camera as processes; all stop together, a death is reported.
"""

from __future__ import annotations

import os
import re
import signal
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
    return [int(p) for p in re.findall(r'started \S+ \(pid (\d+)\)', output)]


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


def test_a_dead_node_stops_the_graph_with_its_reason(ros_env):
    launcher = ros_env.start('launch', 'street')
    _wait_for_nodes(ros_env, ['/cam_street/contours'])
    time.sleep(0.5)
    line = ''
    while 'started' not in line:
        line = launcher.stdout.readline()
    pid = _started_pids(line)[0]
    os.kill(pid, signal.SIGKILL)
    out, _ = launcher.communicate(timeout=30)
    assert launcher.returncode != 0
    assert 'cam_street/contour_node was killed by SIGKILL; stopping the others' in out


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
