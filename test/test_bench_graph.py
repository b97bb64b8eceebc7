"""`memo-ros benchmark graph` on a tiny bag.

The report has every figure with sane values (no timing asserted).
"""

from __future__ import annotations

import json

from memo_ros.tools.benchmarks.graph import parse_rates
from memo_ros.tools.benchmarks.graph_figures import drop_reason
from memo_ros.tools.benchmarks.graph_probe import (
    FrameTrace,
    Restamper,
    header_stamp_ns,
    restamped,
)
from memo_ros.tools.simulate import simulate

NODES = {
    'cam_front/contour_node',
    'cam_side/contour_node',
    'cam_top/contour_node',
    'selector_node',
    'tracker_node',
}


def test_graph_benchmark_reports_every_stage_and_process(ros_env, tmp_path):
    sim = simulate('studio-arm', tmp_path / 'bag', frames=30, width=160, height=120)
    warmup = sim.empty_frames + 5
    out = tmp_path / 'report.json'
    done = ros_env.run(
        'benchmark',
        'graph',
        '--bag',
        sim.bag,
        '--rates',
        '30',
        '--warmup',
        warmup,
        '--json',
        '--out',
        out,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert json.loads(out.read_text()) == report
    assert report['domain_id'] == ros_env.domain_id and report['cameras'] == [
        'cam_front',
        'cam_side',
        'cam_top',
    ]
    (r,) = report['rates']
    frames = sim.frames + sim.empty_frames
    assert (
        r['rate_hz'] == 30.0
        and r['frames_published'] == frames
        and r['timed_frames'] == frames - warmup
    )
    assert r['messages_published'] == {
        f'/{c}/{t}': frames for c in report['cameras'] for t in ('camera_info', 'image_raw')
    }
    assert 0 < r['frames_out'] <= r['timed_frames']
    assert r['frames_dropped'] == r['timed_frames'] - r['frames_out'] == sum(r['drops'].values())
    assert 20.0 < r['input_fps'] < 40.0 and r['output_fps'] > 0
    for name in ('contours', 'assignment', 'joint_states', 'processed'):
        stats = r['latency_ms'][name]
        assert stats is not None and 0 < stats['p50'] <= stats['p99'] <= stats['max'], (
            name,
            stats,
        )
    e2e = r['latency_ms']['joint_states']
    assert e2e['n'] == r['frames_out']
    assert r['stage_ms']['tracker_node']['p50'] > 0
    processes = {p['process']: p for p in r['processes']}
    assert NODES <= set(processes) and {'launcher', 'benchmark (player, probe)'} <= set(processes)
    for name in NODES:
        assert processes[name]['cpu_pct'] > 0 and processes[name]['peak_rss_mb'] > 10, processes[
            name
        ]
    assert set(r['nodes']) == NODES
    assert r['nodes']['tracker_node']['counters']['frames'] >= r['frames_out']
    assert all(
        r['nodes'][f'{c}/contour_node']['images_lost_before_node'] >= 0 for c in report['cameras']
    )
    assert r['target'] is not None and isinstance(r['target']['met'], bool)


def test_graph_benchmark_refuses_bad_rates(ros_env, tmp_path):
    done = ros_env.run('benchmark', 'graph', '--rates', '30,-1')
    assert done.returncode == 2 and 'rates must be positive' in done.stderr
    done = ros_env.run('benchmark', 'graph', '--bag', tmp_path / 'none')
    assert done.returncode == 2 and 'need the bag' in done.stderr
    done = ros_env.run('benchmark', 'graph', '--rig', 'both')
    assert done.returncode == 2 and "unknown rig 'both' for the graph" in done.stderr
    done = ros_env.run('benchmark', 'graph', '--rig', 'ring4', '--bag', tmp_path / 'none')
    assert done.returncode == 2 and 'a --bag has its own' in done.stderr


def test_restamping_gives_a_frame_one_stamp_and_accounts_for_drops():
    assert parse_rates('30, 60') == [30.0, 60.0]
    cdr = bytes([0, 1, 0, 0]) + (7).to_bytes(4, 'little') + (5).to_bytes(4, 'little') + b'rest'
    assert header_stamp_ns(cdr) == 7_000_000_005
    assert header_stamp_ns(restamped(cdr, 12_000_000_003)) == 12_000_000_003
    assert restamped(cdr, 1)[12:] == b'rest'

    class Item:
        def __init__(self, topic: str) -> None:
            self.topic, self.data = topic, cdr

    restamper = Restamper()
    items = [Item('/a/camera_info'), Item('/a/image_raw'), Item('/b/image_raw')]
    for item in items:
        restamper.before_publish(item)
    (trace,) = restamper.frames.values()
    assert {header_stamp_ns(i.data) for i in items} == {trace.stamp} and trace.index == 0
    assert restamper.messages == {'/a/camera_info': 1, '/a/image_raw': 1, '/b/image_raw': 1}

    assert drop_reason(FrameTrace(0, 1, joint_states=5), ['a']) is None
    assert drop_reason(FrameTrace(0, 1, processed=5, outcome='lost'), ['a']) == 'tracker: lost'
    assert drop_reason(FrameTrace(0, 1), ['a']).startswith('no contours nor assignment')
    assert 'contours 1/2, assignment no' in drop_reason(
        FrameTrace(0, 1, contours={'a': 3}), ['a', 'b']
    )
