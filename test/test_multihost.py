"""The graph split over hosts (issue 7).

Network namespaces with their own addresses on a bridge, a camera host running the contour nodes
and the player, a tracking host running the selector and the tracker, DDS discovery by static peers
and Fast DDS's default transports: shared memory within a host, UDP between the hosts (Fast DDS 2.x
tells hosts apart by host name and IPv4 addresses, and the namespaces' addresses differ). The same
end-to-end check as on one host.

Needs root and network namespaces (`ip netns`); skipped, with the reason, where the machine does
not allow them.
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest

from memo_ros.core.simulation.imaging import ImagingOptions
from memo_ros.ros.bagio import read_messages
from memo_ros.tools.evaluate import (
    ESTIMATE_TOPICS,
    TRUTH_TOPICS,
    load_track,
    match_and_measure,
)
from memo_ros.tools.simulate import simulate

ROOT = Path(__file__).resolve().parent.parent
RX_BYTES = '/sys/class/net/eth0/statistics/rx_bytes'  # of a host's interface, in its namespace
SUBNET = '10.{}.{}'  # 10.X.Y.0/24, X.Y from the pid: concurrent runs do not collide


def _last_diagnostics(bag: Path) -> dict[str, dict[str, str]]:
    """Each node's last /diagnostics values recorded in ``bag``."""
    last: dict[str, dict[str, str]] = {}
    for m in read_messages(bag, ['/diagnostics']):
        for status in m.message.status:
            last.setdefault(status.name, {}).update({kv.key: kv.value for kv in status.values})
    return last


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(['ip', *args], capture_output=True, text=True, check=check)


@pytest.fixture
def hosts():
    """Two hosts, ``cams`` and ``track``, as network namespaces on a bridge.

    Their names and addresses.
    """
    if os.geteuid() != 0 or shutil.which('ip') is None:
        pytest.skip(
            'multi-host test skipped: needs root and iproute2 (`ip netns`) for network namespaces'
        )
    tag = os.getpid() % 10000
    net = SUBNET.format(100 + tag // 250 % 100, tag % 250)
    bridge = f'memo_br{tag}'
    names = {'cams': f'memo_cams{tag}', 'track': f'memo_track{tag}'}
    address = {'cams': f'{net}.2', 'track': f'{net}.3'}
    made: list[str] = []
    try:
        try:
            _ip('link', 'add', bridge, 'type', 'bridge')
        except subprocess.CalledProcessError as exc:
            pytest.skip(
                'multi-host test skipped: this machine does not allow network devices: '
                f'{exc.stderr.strip()}'
            )
        made.append(bridge)
        _ip('link', 'set', bridge, 'up')
        for role, ns in names.items():
            try:
                _ip('netns', 'add', ns)
            except subprocess.CalledProcessError as exc:
                pytest.skip(
                    'multi-host test skipped: network namespaces not allowed: '
                    f'{exc.stderr.strip()}'
                )
            made.append(ns)
            veth = f'v{tag}{role[0]}'
            _ip('link', 'add', veth, 'type', 'veth', 'peer', 'name', 'eth0', 'netns', ns)
            _ip('link', 'set', veth, 'master', bridge, 'up')
            _ip('-n', ns, 'addr', 'add', f'{address[role]}/24', 'dev', 'eth0')
            _ip('-n', ns, 'link', 'set', 'eth0', 'up')
            _ip('-n', ns, 'link', 'set', 'lo', 'up')
        yield names, address
    finally:
        for name in made:
            if name == bridge:
                _ip('link', 'del', bridge, check=False)
            else:
                _ip('netns', 'del', name, check=False)


def test_the_graph_split_over_a_camera_host_and_a_tracking_host(hosts, ros_env, tmp_path):
    names, address = hosts
    sim = simulate('studio-walk', tmp_path / 'walk', options=ImagingOptions(noise=3.0))
    env = dict(
        ros_env,
        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
        ROS_STATIC_PEERS=';'.join(address.values()),
    )  # UDP between the hosts, shared memory within one (player to contour nodes), as on real ones

    def on(host: str, *args) -> list[str]:
        return [
            'ip',
            'netns',
            'exec',
            names[host],
            sys.executable,
            '-m',
            'memo_ros.tools.cli',
            *map(str, args),
        ]

    graph = [
        subprocess.Popen(
            on(host, 'launch', sim.studio, '--reliable-images', '--role', role),
            env=env,
            cwd=ROOT,
            text=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        for host, role in (('cams', 'cameras'), ('track', 'tracking'))
    ]
    try:
        # the camera host plays the bag into its contour nodes and records what comes back from the
        # tracking host
        out = tmp_path / 'out'
        replay = subprocess.run(
            on('cams', 'replay', sim.bag, '--no-launch', '--out', out),
            env=env,
            cwd=ROOT,
            text=True,
            capture_output=True,
            timeout=600,
        )
        assert replay.returncode == 0, replay.stderr + replay.stdout
        assert all(p.poll() is None for p in graph), "a host's graph died"
        received = int(_ip('netns', 'exec', names['track'], 'cat', RX_BYTES).stdout)
    finally:
        for p in graph:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        logs = [p.communicate(timeout=30)[0] for p in graph]
    assert all('tracker_node' not in log for log in logs[:1]) and 'tracker_node' in logs[1]
    truth = load_track(sim.bag, TRUTH_TOPICS)
    errors = match_and_measure(truth, load_track(out, ESTIMATE_TOPICS), 1_000_000)
    print(
        f'two hosts: {len(errors.stamps_ns)}/{len(truth.origins)} frames, MPJPE mean '
        f'{errors.mpjpe_mm.mean():.1f} mm, '
        f'worst frame {errors.mpjpe_mm.max():.1f} mm'
    )
    # what a failure on another machine needs to be understood: the worst frames, the replay's
    # report, the nodes' last /diagnostics and their warnings
    worst = np.argsort(errors.mpjpe_mm)[-5:]
    print('worst frames:', {int(i): round(float(errors.mpjpe_mm[i]), 1) for i in sorted(worst)})
    print(replay.stdout)
    for name, values in _last_diagnostics(out).items():
        print(name, values)
    for log in logs:
        print(''.join(line for line in log.splitlines(True) if '[WARN]' in line)[-4000:])
    # the frames' contours cross between the hosts: about 6 MB here (1,484 points a frame of 24
    # bytes, 90 frames, to selector and tracker); 7.0 MB measured
    print(f'the tracking host received {received / 1e6:.1f} MB over its network interface')
    assert len(errors.stamps_ns) == len(truth.origins)
    assert (
        errors.mpjpe_mm.mean() <= 25.0 and errors.mpjpe_mm.max() <= 80.0
    )  # studio-walk, as on one host
