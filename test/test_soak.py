"""A two-minute soak of the live graph at 30 Hz with three 640x480 cameras (issue 7).

Memory stays bounded and every frame is either tracked or counted with its reason.

Runs `memo-ros benchmark graph` (launched graph, best-effort images restamped to the wall clock, a
studio-arm bag played 15 times in a row) and checks its report; the figures are printed with
``pytest -s``.
"""

from __future__ import annotations

import json

import pytest

# the graph at 30 Hz already takes the whole 2-core host; with another test beside it a frame can
# go missing without an outcome (a real failure seen at load 6), so under xdist it runs alone
pytestmark = pytest.mark.exclusive

LOOPS = 15  # 15 passes of 240 frames: 3,600 frames, two minutes at 30 Hz
SUBJECT_FRAMES = 230  # the studio adds 10 empty frames
GROWTH_BOUND_MB = (
    25.0  # resident memory a node may gain once warm: queues and caches, not per frame
)


def test_two_minutes_at_30_hz_memory_bounded_and_every_frame_accounted_for(ros_env):
    result = ros_env.run(
        'benchmark',
        'graph',
        '--rates',
        '30',
        '--frames',
        SUBJECT_FRAMES,
        '--warmup',
        40,
        '--loops',
        LOOPS,
        '--json',
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    r = report['rates'][0]
    print(
        f'soak: {r["frames_published"]} frames in {r["timed_frames"] / r["input_fps"]:.0f} s, '
        f'{r["frames_out"]} tracked, drops {r["drops"]}, outcomes {r["outcomes"]}'
    )
    print(
        'memory warm -> end: '
        + ', '.join(
            f'{m["process"]} {m["rss_warm_mb"]:.0f} -> {m["rss_end_mb"]:.0f}' for m in r['memory']
        )
    )
    assert r['frames_published'] == LOOPS * (SUBJECT_FRAMES + 10)
    assert r['timed_frames'] / r['input_fps'] >= 115.0, 'two minutes of frames'
    # every frame reached the tracker and has its outcome on /memo/processed: tracked, or why not
    outcomes = r['per_frame']['outcome']
    assert None not in outcomes, f'{outcomes.count(None)} frames without an outcome'
    assert sum(r['outcomes'].values()) == r['timed_frames']
    # every image either reached its contour_node or was counted lost by it (up to the last frame
    # or two,
    # which no later image reveals)
    for cam in report['cameras']:
        node = r['nodes'][f'{cam}/contour_node']
        published = r['messages_published'][f'/{cam}/image_raw']
        received, lost = node['counters']['frames_in'], node['dropped'].get('image_lost', 0)
        assert 0 <= published - received - lost <= 2, (cam, published, received, lost)
    # memory: no node grows beyond the bound once warm
    for m in r['memory']:
        if m['process'].endswith('_node'):
            assert m['growth_mb'] is not None and m['growth_mb'] <= GROWTH_BOUND_MB, m
