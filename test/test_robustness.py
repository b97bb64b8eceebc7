"""Issue 17: absurd poses refused, callbacks that never raise out of a node, clean stops.

The node tests run real node processes over DDS (one domain per test) and always stop them.
"""

from __future__ import annotations

import signal
import subprocess
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from sensor_msgs.msg import JointState, PointCloud2
from std_srvs.srv import Trigger
from test_selector_node import Feeder
from test_tracker_node import _cloud, _studio_arm
from test_tracking_core import _silhouette_contours

from memo_ros.core.formats.studio import Studio, studio_path
from memo_ros.core.geometry.body import load_studio_actor
from memo_ros.core.geometry.render import render, render_labels
from memo_ros.core.multiview.anatomy import JOINT_LIMITS, pose_problem, studio_volume
from memo_ros.core.multiview.motion import named_values_problem
from memo_ros.core.multiview.tracking import TRACKING, ArticulatedTracker
from memo_ros.core.simulation.scenarios import make_scenario, studio_cameras
from memo_ros.ros.assignment_messages import assignment_from_message
from memo_ros.ros.body_messages import stamp_from_ns
from memo_ros.ros.dds import ros_session
from memo_ros.ros.health import NodeHealth

BODY = load_studio_actor()
NAMES = list(BODY.coordinate_names)
NS = 1_000_000_000
T0 = 1_800_000_000 * NS
DT = 33_333_333
STOP_TIMEOUT_S = 30.0


def _q(**values: float) -> np.ndarray:
    q = BODY.neutral()
    for name, value in values.items():
        q[NAMES.index(name)] = value
    return q


# ---------------------------------------------------------------- the core


def test_pose_problem_refuses_absurd_poses_with_a_reason_and_accepts_real_ones():
    scenario = make_scenario('studio-arm', BODY)
    volume = studio_volume(scenario.cameras)
    low, high = volume
    assert np.all(low[:2] <= -4.0) and np.all(high[:2] >= 4.0)  # around the cameras
    assert (low[2], high[2]) == (-1.0, 4.0)
    assert pose_problem(BODY, BODY.neutral(), volume) is None
    for name in ('studio-arm', 'studio-walk', 'street-walk'):
        s = make_scenario(name, BODY)
        q, _ = s.coordinates(np.arange(s.frames) / s.frame_rate)
        assert [pose_problem(BODY, x, studio_volume(s.cameras)) for x in q] == [None] * len(q)
    cases = {
        'outside the studio volume': _q(root_tx=1e300),
        'root_tz': _q(root_tz=np.nan),  # not finite, named
        'knee_l_y = 3 rad is outside its range': _q(knee_l_y=3.0),
        'elbow_r_y': _q(elbow_r_y=-0.5),
        'rotation vector of hip_l': _q(hip_l_x=7.0),
        'rotation vector of root': _q(root_rz=-6.5),
        'elbow_l_z = 7 rad is more than 2 pi': _q(elbow_l_z=7.0),
        'a pose needs 33 coordinates': BODY.neutral()[:5],
    }
    assert len(NAMES) == 33
    for reason, q in cases.items():
        problem = pose_problem(BODY, q, volume)
        assert problem is not None and reason in problem and '\n' not in problem, (reason, problem)
    # a small tolerance at the ranges; no volume: the root may be anywhere; limits can be left out
    lo, _ = JOINT_LIMITS['knee_l_y']
    assert pose_problem(BODY, _q(knee_l_y=lo - 0.05), volume) is None
    assert pose_problem(BODY, _q(root_tx=50.0), None) is None
    assert pose_problem(BODY, _q(knee_l_y=3.0), volume, limits=False) is None
    assert studio_volume([]) is None


def test_named_values_problem_refuses_cut_duplicate_and_empty_lists():
    assert named_values_problem(NAMES[:6], [0.0] * 6) is None
    assert named_values_problem(NAMES[:6], [0.0, 1.0]) == '6 names but 2 positions'
    assert 'root_tx' in named_values_problem(['root_tx', 'root_ty', 'root_tx'], [0, 1, 2])
    assert 'empty' in named_values_problem([], [])


def test_set_pose_refuses_an_absurd_pose_and_leaves_the_filter_as_it_was():
    scenario = make_scenario('studio-arm', BODY, frames=4)
    q, _ = scenario.coordinates(np.arange(3) / scenario.frame_rate)
    tracker = ArticulatedTracker(BODY, scenario.cameras, initial_pose=q[0])
    for k in range(2):
        assert (
            tracker.step(k * DT, _silhouette_contours(scenario.cameras, q[k])).status == TRACKING
        )
    before = (tracker.ekf.q.copy(), tracker.ekf.P.copy(), tracker.status, tracker.stamp_ns)
    pending = tracker.pending_pose
    for absurd, reason in (
        (_q(root_tx=1e300), 'outside the studio volume'),
        (_q(root_ty=np.nan), 'not finite'),
        (_q(knee_r_y=3.0), 'knee_r_y'),
    ):
        with pytest.raises(ValueError, match=reason):
            tracker.set_pose(absurd)
        assert np.array_equal(tracker.ekf.q, before[0]) and np.array_equal(
            tracker.ekf.P, before[1]
        )
        assert (tracker.status, tracker.stamp_ns) == before[2:]
        assert tracker.pending_pose is pending
    result = tracker.step(2 * DT, _silhouette_contours(scenario.cameras, q[2]))
    assert result.status == TRACKING and not result.initialised
    tracker.set_pose(q[2])  # a real pose is taken
    assert np.array_equal(tracker.pending_pose, q[2]) and tracker.status != TRACKING


def test_render_labels_skips_parts_posed_absurdly_instead_of_indexing_out_of_the_image():
    cameras = studio_cameras()
    for value in (1e300, 1e18, np.inf, np.nan):
        with np.errstate(all='ignore'):
            rotations, origins = BODY.forward_kinematics(_q(root_tx=value))
        for camera in cameras:
            for scale in (1.0, 0.25):
                rendering = render_labels(
                    camera, rotations, origins, BODY.semi_axes, BODY.lengths, scale
                )
                assert not rendering.unoccluded_area.any() and not rendering.label.any()
    # a part reaching towards a camera's plane: clipped to the image, as render() does
    camera = cameras[0]
    rotations, origins = BODY.forward_kinematics(_q(root_tx=camera.centre[0] - 0.35))
    fast = render_labels(camera, rotations, origins, BODY.semi_axes, BODY.lengths, 0.25)
    exact = render(camera, rotations, origins, BODY.semi_axes, BODY.lengths, 0.25)
    assert fast.label.any() and np.array_equal(fast.label, exact.label)


def test_a_callback_that_raises_is_counted_and_the_node_goes_on(ros_env):
    with ros_session('guard_probe', ros_env.domain_id) as (node, _):
        health = NodeHealth(node, 'guard_probe')

        def broken(*_):
            raise RuntimeError('boom')

        subscription = health.guard(broken, 'a callback')
        assert subscription(object()) is None and subscription(object()) is None
        response = health.guard(broken, 'a service', service=True)(
            Trigger.Request(), Trigger.Response(success=True)
        )
        assert not response.success and 'boom' in response.message
        assert health.dropped['internal_error'] == 3
        values = {kv.key: kv.value for kv in health.status().values}
        assert values['dropped.internal_error'] == '3' and 'boom' in values['last_problem']


# ---------------------------------------------------------------- nodes over DDS


class Diagnostics:
    """Every node's newest /diagnostics values by status name, and a spin helper."""

    def __init__(self, node, executor) -> None:
        self.node, self.executor = node, executor
        self.values: dict[str, dict[str, str]] = {}
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.values.setdefault(status.name, {}).update(
                {kv.key: kv.value for kv in status.values}
            )

    def spin(self, seconds: float) -> None:
        """Spin the probe for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)

    def until(self, condition, timeout: float = 30.0, what: str = '') -> None:
        """Spin until ``condition()`` holds; fail after ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < end, f'timed out: {what} {self.values}'
            self.spin(0.05)


def _tracker(ros_env, studio, name: str = 'tracker_node') -> subprocess.Popen:
    return ros_env.start_node(
        'tracker_node',
        '--params-file',
        studio,
        '-r',
        f'__node:={name}',
        '-p',
        'wait_for_assignment:=false',
        '-p',
        'join_timeout:=0.05',
    )


def _stop(process: subprocess.Popen, sig: int = signal.SIGTERM, twice: bool = False) -> str:
    """Stop a node with ``sig`` (``twice``: again 50 ms later, as Ctrl-C under ros2 launch)."""
    process.send_signal(sig)
    if twice:
        time.sleep(0.05)
        if process.poll() is None:
            process.send_signal(sig)
    try:
        out, _ = process.communicate(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        out, _ = process.communicate()
        pytest.fail(f'the node did not stop on {signal.Signals(sig).name}:\n{out[-3000:]}')
    return out


def _set_pose(names, positions) -> JointState:
    return JointState(name=list(names), position=[float(v) for v in positions])


def test_tracker_refuses_absurd_set_poses_and_keeps_tracking(ros_env, tmp_path):
    scenario, q, studio = _studio_arm(tmp_path, 16)
    cams = [c.name for c in scenario.cameras]
    tables = [_silhouette_contours(scenario.cameras, q[k]) for k in range(len(q))]
    process = _tracker(ros_env, studio)
    try:
        with ros_session('set_pose_feeder', ros_env.domain_id) as (node, executor):
            diag = Diagnostics(node, executor)
            pubs = {c: node.create_publisher(PointCloud2, f'/{c}/contours', 10) for c in cams}
            set_pose = node.create_publisher(JointState, '/tracker_node/set_pose', 10)
            joints: dict[int, JointState] = {}
            node.create_subscription(
                JointState,
                '/memo/joint_states',
                lambda m: joints.__setitem__(m.header.stamp.sec * NS + m.header.stamp.nanosec, m),
                100,
            )
            diag.until(
                lambda: (
                    all(p.get_subscription_count() for p in pubs.values())
                    and set_pose.get_subscription_count()
                ),
                what='tracker_node subscriptions',
            )
            diag.spin(0.5)

            def send(k: int) -> None:
                for cam in cams:
                    pubs[cam].publish(_cloud(tables[k][cam], T0 + k * DT))
                diag.spin(0.25)

            for k in range(4):
                send(k)
            diag.until(lambda: len(joints) >= 4, what='the first estimates')
            absurd = [
                _set_pose(['root_tx'], [1e300]),
                _set_pose(['root_ty'], [np.nan]),
                _set_pose(['knee_l_y'], [3.0]),
            ]
            malformed = [
                _set_pose(NAMES[:6], [0.1, 0.2]),  # six names, two positions
                _set_pose(['root_tx', 'root_ty', 'root_tx'], [0.0, 0.1, 0.2]),  # a duplicate
                JointState(),  # empty
                _set_pose(['knee_x'], [0.0]),  # unknown coordinate
            ]
            for msg in absurd + malformed:
                set_pose.publish(msg)
            diag.spin(0.3)
            for k in range(4, 12):
                send(k)
            diag.until(lambda: T0 + 11 * DT in joints, what='estimates after the refusals')
            expected = {'dropped.absurd_set_pose': '3', 'dropped.bad_set_pose': '4'}
            diag.until(
                lambda: expected.items() <= diag.values.get('/tracker_node', {}).items(),
                what='refusals counted',
            )
            values = diag.values['/tracker_node']
            assert 'set_pose' not in values and values['tracking_state'] == TRACKING
            assert values['initialisations'] == '1'  # the start only: the filter went on
            assert len(joints) == 12  # every frame tracked, none lost
            last = np.array(joints[T0 + 11 * DT].position)
            assert np.abs(last[:3] - q[11][:3]).max() < 0.05
            hand = NAMES.index('shoulder_r_y')
            assert abs(last[hand] - q[11][hand]) < 0.1
            # a real pose is still taken
            set_pose.publish(_set_pose(NAMES, q[12]))
            diag.spin(0.3)
            for k in range(12, 16):
                send(k)
            diag.until(lambda: T0 + 15 * DT in joints, what='estimates after a real set_pose')
            diag.until(lambda: diag.values['/tracker_node'].get('set_pose') == '1', what='set')
        assert process.poll() is None, 'the tracker must keep running'
    finally:
        out = _stop(process)
    assert process.returncode == 0 and 'Traceback' not in out, out[-3000:]
    assert 'set_pose refused' in out, out  # one line: the log is throttled


def test_an_absurd_initial_pose_is_refused_and_the_tracker_starts_from_the_silhouettes(
    ros_env, tmp_path
):
    initial = dict(zip(NAMES, map(float, _q(knee_r_y=3.0))))
    scenario, q, studio = _studio_arm(tmp_path, 6, initial)
    cams = [c.name for c in scenario.cameras]
    process = _tracker(ros_env, studio)
    try:
        with ros_session('initial_pose_feeder', ros_env.domain_id) as (node, executor):
            diag = Diagnostics(node, executor)
            pubs = {c: node.create_publisher(PointCloud2, f'/{c}/contours', 10) for c in cams}
            joints = []
            node.create_subscription(JointState, '/memo/joint_states', joints.append, 100)
            diag.until(lambda: all(p.get_subscription_count() for p in pubs.values()))
            diag.spin(0.5)
            for k in range(len(q)):
                tables = _silhouette_contours(scenario.cameras, q[k])
                for cam in cams:
                    pubs[cam].publish(_cloud(tables[cam], T0 + k * DT))
                diag.spin(0.3)
            diag.until(lambda: len(joints) >= 1, what='an estimate from the silhouettes')
            diag.until(lambda: 'initial_pose' in diag.values.get('/tracker_node', {}))
            assert diag.values['/tracker_node']['initial_pose'] == 'silhouettes'
    finally:
        out = _stop(process)
    assert process.returncode == 0 and 'Traceback' not in out, out[-3000:]
    lines = [line for line in out.splitlines() if 'initial_pose is refused' in line]
    assert len(lines) == 1 and 'knee_r_y = 3 rad' in lines[0], out[-3000:]


def test_selector_refuses_absurd_joint_states_and_keeps_assigning(ros_env):
    studio = studio_path('studio_orthogonal')
    process = ros_env.start_node(
        'selector_node', '--params-file', studio, '-p', 'require_contours:=false'
    )
    names = ['cam_front', 'cam_side', 'cam_top']
    try:
        with ros_session('selector_feeder', ros_env.domain_id) as (node, executor):
            feed = Feeder(node, executor, Studio.load(studio).cameras)
            feed.wait_for_node()
            q = BODY.neutral()

            def joints(stamp, q=q, qdot=None, names=NAMES):
                msg = _set_pose(names, q)
                msg.velocity = [float(v) for v in (np.zeros(len(q)) if qdot is None else qdot)]
                msg.header.stamp = stamp_from_ns(stamp)
                feed.joints.publish(msg)

            joints(1 * NS)  # the last good posterior
            joints(1 * NS + 5_000_000, _q(root_tx=1e300))
            joints(1 * NS + 10_000_000, _q(knee_l_y=3.0))
            joints(
                1 * NS + 15_000_000, np.append(q, 0.0), names=NAMES + ['root_tx']
            )  # a duplicate
            feed.spin(0.3)
            t1 = 1 * NS + NS // 30
            feed.frame(t1, names)
            feed.wait_for(lambda: t1 in feed.assignments)
            assert assignment_from_message(feed.assignments[t1]).mode == 'predicted'
            # finite but absurd rates: the prediction is refused, every camera assigned
            qdot = np.zeros(len(q))
            qdot[0] = 1e300
            joints(1 * NS + NS // 10, qdot=qdot)
            feed.spin(0.3)
            t2 = 1 * NS + NS // 10 + NS // 30
            feed.frame(t2, names)
            feed.wait_for(lambda: t2 in feed.assignments)
            assert assignment_from_message(feed.assignments[t2]).mode == 'all_cameras'
            expected = {
                'dropped.absurd_joint_state': '2',
                'dropped.bad_joint_state': '1',
                'absurd_prediction': '1',
                'assignments_published': '2',
            }
            feed.wait_for(lambda: expected.items() <= feed.diagnostics.items(), timeout=15)
            assert 'dropped.internal_error' not in feed.diagnostics
        assert process.poll() is None, 'the selector must keep running'
    finally:
        out = _stop(process, signal.SIGINT, twice=True)
    assert process.returncode == 0 and 'Traceback' not in out, out[-3000:]
    assert 'joint_states refused' in out


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT], ids=['SIGTERM', 'SIGINT'])
def test_every_node_exits_zero_on_a_stop_signal_even_mid_frame(ros_env, tmp_path, sig):
    scenario, q, studio = _studio_arm(tmp_path, 8)
    cams = [c.name for c in scenario.cameras]
    tables = [_silhouette_contours(scenario.cameras, q[k]) for k in range(len(q))]
    processes = {
        '/cam_stop/contour_node': ros_env.start_node('contour_node', '-r', '__ns:=/cam_stop'),
        '/selector_stop': ros_env.start_node(
            'selector_node', '--params-file', studio, '-r', '__node:=selector_stop'
        ),
        '/tracker_stop': _tracker(ros_env, studio, 'tracker_stop'),
        '/walker_stop': ros_env.start_node(
            'walker_node', '--params-file', studio_path('street'), '-r', '__node:=walker_stop'
        ),
    }
    outputs = {}
    try:
        with ros_session('stop_feeder', ros_env.domain_id) as (node, executor):
            diag = Diagnostics(node, executor)
            pubs = {c: node.create_publisher(PointCloud2, f'/{c}/contours', 10) for c in cams}
            diag.until(
                lambda: (
                    set(processes) <= set(diag.values)
                    and all(p.get_subscription_count() for p in pubs.values())
                ),
                timeout=45,
                what='every node up',
            )
            # keep the tracker busy: frames back to back, the signal comes in the middle of one
            k = 0

            def stream(seconds: float) -> None:
                nonlocal k
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    for cam in cams:
                        pubs[cam].publish(_cloud(tables[k % len(q)][cam], T0 + k * DT))
                    k += 1
                    diag.spin(0.02)

            stream(1.5)
            assert 'frames' in diag.values['/tracker_stop']
            for process in processes.values():
                process.send_signal(sig)
            stream(0.05)
            if sig == signal.SIGINT:  # Ctrl-C under ros2 launch: the terminal's and launch's
                for process in processes.values():
                    if process.poll() is None:
                        process.send_signal(sig)
            stream(0.5)
    finally:
        for name, process in processes.items():
            outputs[name] = _stop(process, sig)
    for name, process in processes.items():
        out = outputs[name]
        assert process.returncode == 0, f'{name} exited {process.returncode}:\n{out[-3000:]}'
        assert 'Traceback' not in out and 'KeyboardInterrupt' not in out, f'{name}:\n{out[-3000:]}'
        assert 'stopping on a signal' in out, f'{name}:\n{out[-3000:]}'
