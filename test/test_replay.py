"""`memo-ros replay`.

The live graph paced by back-pressure, every frame processed and its outputs recorded.
"""

from __future__ import annotations

import struct
import threading
import time
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from memo_ros.ros.bagio import bag_topics, read_messages, stamp_to_ns
from memo_ros.ros.dds import MatchedOnDiagnostics
from memo_ros.tools.replay import Pacer
from memo_ros.tools.simulate import simulate


def test_replay_processes_every_frame_and_records_the_outputs(ros_env, tmp_path):
    sim = simulate('studio-arm', tmp_path / 'arm', frames=15)
    out = tmp_path / 'tracked'
    done = ros_env.run('replay', sim.bag, '--out', out, timeout=180)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'did not confirm' not in done.stderr  # every node reported its side of the matches
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


def test_the_nodes_side_of_each_match_is_read_from_their_diagnostics():
    class Node:  # only what MatchedOnDiagnostics asks of its node
        def create_subscription(self, msg_type, topic, callback, depth):
            self.callback = callback

    node = Node()
    matched = MatchedOnDiagnostics(node)
    wanted = {'publishers./cam/image_raw': 1, 'subscribers./memo/markers': 4}
    assert matched.missing(wanted) == list(wanted)

    def report(name: str, values: dict[str, str]) -> DiagnosticArray:
        status = DiagnosticStatus(name=name)
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        return DiagnosticArray(status=[status])

    node.callback(report('/cam/contour_node', {'publishers./cam/image_raw': '1'}))
    node.callback(report('/tracker_node', {'subscribers./memo/markers': '3', 'frames': '9'}))
    assert matched.missing(wanted) == ['subscribers./memo/markers']  # the recorder not yet
    node.callback(report('/tracker_node', {'subscribers./memo/markers': '4'}))
    assert matched.missing(wanted) == []


def test_the_pacer_waits_for_a_long_start_while_the_tracker_works_on_it():
    """Frame 0 takes 1 s (a start): the tracker's working_on keeps the wait past the 0.3 s timeout.

    The other nodes' diagnostics, or the tracker's while idle (killed and restarted, the frame
    lost with it), do not: such a wait gives up after the timeout and is counted.
    """

    def frame(stamp_ns: int):
        return SimpleNamespace(data=b'\0' * 4 + struct.pack('<iI', 0, stamp_ns))

    def done(stamp_ns: int):
        return SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=stamp_ns))

    def diagnostics(node: str, working_on: str):
        status = DiagnosticStatus(name=node, values=[KeyValue(key='working_on', value=working_on)])
        return DiagnosticArray(status=[status])

    pacer = Pacer(timeout=0.3)
    pacer.before_publish(frame(1000), pace=True)

    def graph() -> None:
        for _ in range(10):
            time.sleep(0.1)
            pacer.on_diagnostics(diagnostics('/tracker_node', '1000'))
        pacer.on_processed(done(1000))

    worker = threading.Thread(target=graph)
    start = time.monotonic()
    worker.start()
    pacer.before_publish(frame(2000), pace=True)  # waits for frame 1000 to be done
    waited = time.monotonic() - start
    worker.join()
    assert pacer.timeouts == 0 and waited >= 0.9, waited

    def idle() -> None:
        for _ in range(10):
            time.sleep(0.1)
            pacer.on_diagnostics(diagnostics('/tracker_node', ''))
            pacer.on_diagnostics(diagnostics('/cam/contour_node', ''))

    worker = threading.Thread(target=idle)
    start = time.monotonic()
    worker.start()
    pacer.before_publish(frame(3000), pace=True)  # frame 2000 never done, no tracker at work
    waited = time.monotonic() - start
    worker.join()
    assert pacer.timeouts == 1 and 0.3 <= waited < 0.9, waited
    assert pacer.frames == 3
