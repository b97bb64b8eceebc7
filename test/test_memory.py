"""Oversized inputs cost no lasting memory: every node stays within 50 MB of its warm size.

A studio-arm graph is launched and warmed with a good bag; then every camera gets 4k images
(on a VGA camera) and every contour topic a 2-million-point cloud.  The nodes refuse both
before reading them; what must not stay is the buffers DDS and the allocator held them in (before
config/fastdds_node_memory.xml and a fixed mmap threshold: +190 MB in the selector and the
tracker, +23-46 MB per contour_node).
"""

from __future__ import annotations

from pathlib import Path
import threading
import time

import numpy as np
from sensor_msgs.msg import Image, PointCloud2, PointField

from memo_ros.core.formats.studio import Studio
from memo_ros.ros.dds import ros_session
from memo_ros.tools.proc_stats import children, rss_mb
from memo_ros.tools.simulate import simulate

ALLOWED_GROWTH_MB = 50.0
NODES = ('contour_node', 'selector_node', 'tracker_node')


def _node_processes(launcher_pid: int) -> dict[str, int]:
    """Return each launched node's pid, named by its role and namespace."""
    found = {}
    for pid, command in children(launcher_pid).items():
        role = next((n for n in NODES if any(n in word for word in command)), None)
        if role:
            namespace = next((w for w in command if w.startswith('__ns:=')), '')
            found[f'{role}{namespace[5:]}'] = pid
    return found


def _cloud(points: int) -> PointCloud2:
    fields = [
        PointField(name=name, offset=4 * k, datatype=PointField.FLOAT32, count=1)
        for k, name in enumerate(('x', 'y', 'tx', 'ty'))
    ]
    fields.append(PointField(name='contour', offset=16, datatype=PointField.INT32, count=1))
    msg = PointCloud2(height=1, width=points, fields=fields, point_step=20)
    msg.row_step = 20 * points
    msg.data = np.zeros(20 * points, np.uint8).tobytes()
    return msg


def test_nodes_stay_within_50_mb_of_their_warm_size_after_oversized_inputs(ros_env, tmp_path):
    sim = simulate('studio-arm', tmp_path / 'arm', frames=20)
    studio_file = Path(str(sim.bag) + '.yaml')
    cameras = Studio.load(studio_file).camera_names
    launcher = ros_env.start('launch', studio_file, '--reliable-images')
    output: list[str] = []
    threading.Thread(target=lambda: output.extend(launcher.stdout), daemon=True).start()
    done = ros_env.run('replay', sim.bag, '--out', tmp_path / 'warm', '--no-launch', timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    pids = _node_processes(launcher.pid)
    assert len(pids) == len(cameras) + 2, (pids, output[-20:])
    warm = {name: rss_mb(pid) for name, pid in pids.items()}

    with ros_session('oversized', ros_env.domain_id) as (node, executor):
        image_pubs = [node.create_publisher(Image, f'/{c}/image_raw', 10) for c in cameras]
        cloud_pubs = [node.create_publisher(PointCloud2, f'/{c}/contours', 10) for c in cameras]
        deadline = time.monotonic() + 30
        while not all(p.get_subscription_count() for p in image_pubs + cloud_pubs):
            executor.spin_once(timeout_sec=0.1)
            assert time.monotonic() < deadline, 'the graph did not subscribe'
        big = Image(encoding='rgb8', width=3840, height=2160, step=3 * 3840)
        big.data = np.full(3 * 3840 * 2160, 128, np.uint8).tobytes()
        cloud = _cloud(2_000_000)
        for k in range(3):
            for publishers, msg in ((image_pubs, big), (cloud_pubs, cloud)):
                msg.header.stamp.sec = 2_000_000_000 + k
                for publisher in publishers:
                    publisher.publish(msg)
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.1)
    time.sleep(3.0)
    after = {name: rss_mb(pid) for name, pid in pids.items()}
    growth = {name: after[name] - warm[name] for name in pids}
    print('resident MB warm / after:', {n: f'{warm[n]:.0f} / {after[n]:.0f}' for n in pids})
    assert launcher.poll() is None, output[-20:]
    assert all(g <= ALLOWED_GROWTH_MB for g in growth.values()), growth
