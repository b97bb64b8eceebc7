"""`memo-ros replay`.

The live graph paced by back-pressure, every frame processed and its outputs recorded.
"""

from __future__ import annotations

from memo_ros.ros.bagio import bag_topics, read_messages, stamp_to_ns
from memo_ros.tools.simulate import simulate


def test_replay_processes_every_frame_and_records_the_outputs(ros_env, tmp_path):
    sim = simulate('studio-arm', tmp_path / 'arm', frames=15)
    out = tmp_path / 'tracked'
    done = ros_env.run('replay', sim.bag, '--out', out, timeout=180)
    assert done.returncode == 0, done.stdout + done.stderr
    frames = 15 + sim.empty_frames
    assert (
        f'replayed   {frames} frames' in done.stdout
        and f'processed  {frames} frames' in done.stdout
    ), done.stdout
    topics = bag_topics(out)
    assert {
        '/memo/joint_states',
        '/memo/body_poses',
        '/memo/camera_assignment',
        '/memo/processed',
    } <= set(topics)
    truth = [
        stamp_to_ns(m.message.header.stamp)
        for m in read_messages(sim.bag, ['/memo/truth/joint_states'])
    ]
    tracked = [
        stamp_to_ns(m.message.header.stamp) for m in read_messages(out, ['/memo/joint_states'])
    ]
    assert tracked == truth  # one estimate per frame with the subject, in order


def test_replay_refuses_bad_arguments_in_one_line(ros_env, tmp_path):
    missing = ros_env.run('replay', tmp_path / 'nothing', '--out', tmp_path / 'out')
    assert (
        missing.returncode == 2 and missing.stderr.count('\n') == 1 and 'no bag' in missing.stderr
    )
