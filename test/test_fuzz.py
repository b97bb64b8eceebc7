"""Fuzz the live graph: generated messages on every input topic and service, then a good bag.

Hypothesis generates images, camera_infos, contour clouds, camera assignments, joint states,
set_pose requests, markers and reset calls, mostly malformed or absurd, and sends them over DDS
to the five node processes of a launched studio-arm graph.  Afterwards no node has died or been
restarted, none met an unexpected exception (``internal_error``), every node counted refusals
under their reasons, and a good bag replayed into the same graph tracks within 10 % of a fresh
graph's MPJPE.  ``MEMO_ROS_FUZZ_MESSAGES`` sets the number of messages (CI: 2,100).
"""

from __future__ import annotations

import os
from pathlib import Path
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import CameraInfo, Image, JointState, PointCloud2, PointField
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import PART_NAMES
from memo_ros.ros.dds import ros_session
from memo_ros.tools.evaluate import ESTIMATE_TOPICS, TRUTH_TOPICS, load_track, match_and_measure
from memo_ros.tools.simulate import simulate

MESSAGES = int(os.environ.get('MEMO_ROS_FUZZ_MESSAGES', '2100'))
FUZZ_EPOCH_S = 1_900_000_000  # after the simulated bag's stamps: the bag then jumps back in time
ENCODINGS = ['mono8', 'mono16', 'rgb8', 'bgr8', 'rgba8', 'bgra8', 'yuv422', '', '8UC1', 'x' * 40]
MODELS = ['plumb_bob', 'rational_polynomial', 'equidistant', '', 'none', 'fisheye']
NODES = ('contour_node', 'selector_node', 'tracker_node')
FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-5.0, 5.0),
    st.sampled_from([0.0, 1e300, -1e300, float('nan')]),
)


def _stamp(msg, sec: int, nanosec: int) -> None:
    msg.header.stamp.sec = FUZZ_EPOCH_S + sec
    msg.header.stamp.nanosec = nanosec


@st.composite
def images(draw, size: tuple[int, int]) -> Image:
    msg = Image(encoding=draw(st.sampled_from(ENCODINGS)))
    if draw(st.booleans()):  # the camera's own size, mono8: a picture that is read
        msg.width, msg.height, msg.step = size[0], size[1], size[0]
        msg.encoding = 'mono8'
        msg.data = draw(st.binary(min_size=16, max_size=16)) * (size[0] * size[1] // 16)
    else:
        msg.width, msg.height = draw(st.integers(0, 5000)), draw(st.integers(0, 5000))
        msg.step = draw(st.integers(0, 20000))
        msg.data = draw(st.binary(max_size=4096))
    msg.is_bigendian = draw(st.integers(0, 1))
    return msg


@st.composite
def camera_infos(draw) -> CameraInfo:
    msg = CameraInfo(distortion_model=draw(st.sampled_from(MODELS)))
    msg.width, msg.height = draw(st.integers(0, 5000)), draw(st.integers(0, 5000))
    msg.k = [draw(FLOATS) for _ in range(9)]
    msg.d = [draw(FLOATS) for _ in range(draw(st.integers(0, 12)))]
    return msg


@st.composite
def clouds(draw) -> PointCloud2:
    names = draw(st.lists(st.sampled_from(['x', 'y', 'tx', 'ty', 'contour', 'z']), max_size=6))
    fields, offset = [], 0
    for name in names:
        datatype = draw(st.integers(1, 8))
        fields.append(PointField(name=name, offset=offset, datatype=datatype, count=1))
        offset += draw(st.integers(0, 8))
    msg = PointCloud2(fields=fields, point_step=draw(st.integers(0, 64)))
    msg.height = draw(st.integers(0, 3))
    msg.width = draw(st.one_of(st.integers(0, 2000), st.just(5_000_000)))
    msg.row_step = draw(st.integers(0, 100000))
    msg.data = draw(st.binary(max_size=8192))
    msg.is_bigendian = draw(st.booleans())
    return msg


@st.composite
def assignments(draw, cameras: list[str]) -> DiagnosticArray:
    names = st.one_of(st.sampled_from(PART_NAMES), st.text(max_size=12))
    keys = st.one_of(
        st.sampled_from([f'{c}.{k}' for c in cameras for k in ('vi', 'obs', 'selected')]),
        st.text(max_size=8),
    )
    values = st.one_of(
        st.sampled_from(['nan', 'true', 'false', '1e300', '-1']), st.text(max_size=8)
    )
    status = st.builds(
        DiagnosticStatus,
        name=names,
        values=st.lists(st.builds(KeyValue, key=keys, value=values), max_size=8),
    )
    return DiagnosticArray(status=draw(st.lists(status, max_size=16)))


@st.composite
def joint_states(draw, coordinates: list[str]) -> JointState:
    names = draw(
        st.lists(st.one_of(st.sampled_from(coordinates), st.text(max_size=8)), max_size=70)
    )
    count = draw(st.one_of(st.just(len(names)), st.integers(0, 70)))
    msg = JointState(name=names, position=[draw(FLOATS) for _ in range(count)])
    msg.velocity = [draw(FLOATS) for _ in range(draw(st.integers(0, 3)))]
    return msg


@st.composite
def marker_arrays(draw) -> MarkerArray:
    def marker(k: int) -> Marker:
        m = Marker(
            id=k, type=draw(st.sampled_from([Marker.CYLINDER, Marker.TEXT_VIEW_FACING, 99]))
        )
        m.pose.position.x, m.pose.position.y, m.pose.position.z = (draw(FLOATS) for _ in range(3))
        m.pose.orientation.w = draw(FLOATS)
        m.scale.x, m.scale.y, m.scale.z = (draw(FLOATS) for _ in range(3))
        return m

    return MarkerArray(markers=[marker(k) for k in range(draw(st.integers(0, 20)))])


def _diagnostics(node, executor, seconds: float) -> dict[str, dict[str, str]]:
    """Return each node's latest /diagnostics values, gathered for ``seconds``."""
    found: dict[str, dict[str, str]] = {}

    def on_message(msg: DiagnosticArray) -> None:
        for status in msg.status:
            found.setdefault(status.name, {}).update({v.key: v.value for v in status.values})

    subscription = node.create_subscription(DiagnosticArray, '/diagnostics', on_message, 100)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    node.destroy_subscription(subscription)
    return found


def _mpjpe(ros_env, bag: Path, out: Path, *options: str) -> float:
    done = ros_env.run('replay', bag, '--out', out, *options, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    truth, estimate = load_track(bag, TRUTH_TOPICS), load_track(out, ESTIMATE_TOPICS)
    errors = match_and_measure(truth, estimate, 1_000_000)
    return float(errors.mpjpe_mm.mean())


def test_fuzzed_graph_survives_counts_and_still_tracks(ros_env, tmp_path):
    sim = simulate('studio-arm', tmp_path / 'arm', frames=30)
    studio_file = Path(str(sim.bag) + '.yaml')
    studio = Studio.load(studio_file)
    cameras = studio.camera_names
    fresh = _mpjpe(ros_env, sim.bag, tmp_path / 'fresh')

    launcher = ros_env.start('launch', studio_file, '--reliable-images')
    output: list[str] = []  # drained, so the launcher never blocks on a full pipe
    threading.Thread(target=lambda: output.extend(launcher.stdout), daemon=True).start()
    sent: dict[str, int] = {}
    with ros_session('fuzzer', ros_env.domain_id) as (node, executor):
        types = {'image_raw': Image, 'camera_info': CameraInfo, 'contours': PointCloud2}
        topics = {f'/{c}/{kind}': t for c in cameras for kind, t in types.items()}
        topics.update({
            '/memo/camera_assignment': DiagnosticArray,
            '/memo/joint_states': JointState,
            '/tracker_node/set_pose': JointState,
            '/memo/markers': MarkerArray,
        })  # fmt: skip
        publishers = {t: node.create_publisher(kind, t, 100) for t, kind in topics.items()}
        reset = node.create_client(Trigger, '/tracker_node/reset')
        deadline = time.monotonic() + 60
        required = [t for t in publishers if t != '/memo/markers']  # markers: a tracked region
        while not all(publishers[t].get_subscription_count() for t in required):
            missing = [t for t in required if not publishers[t].get_subscription_count()]
            assert time.monotonic() < deadline, f'the graph did not subscribe {missing}'
            executor.spin_once(timeout_sec=0.1)
        size = (studio.cameras[0].width, studio.cameras[0].height)
        coordinates = list(studio.body.coordinate_names)
        strategies = {
            'image_raw': images(size),
            'camera_info': camera_infos(),
            'contours': clouds(),
            '/memo/camera_assignment': assignments(cameras),
            '/memo/joint_states': joint_states(coordinates),
            '/tracker_node/set_pose': joint_states(coordinates),
            '/memo/markers': marker_arrays(),
        }
        counter = iter(range(10**9))

        @settings(
            max_examples=MESSAGES,
            deadline=None,
            database=None,
            derandomize=True,
            suppress_health_check=list(HealthCheck),
        )
        @given(st.data())
        def send(data) -> None:
            k = next(counter)
            if k % 200 == 199:  # the service too
                reset.call_async(Trigger.Request())
                sent['reset'] = sent.get('reset', 0) + 1
            topic = data.draw(st.sampled_from(sorted(publishers)))
            kind = topic if topic in strategies else topic.rsplit('/', 1)[-1]
            msg = data.draw(strategies[kind])
            if hasattr(msg, 'header'):
                _stamp(msg, k // 20, (k % 20) * 50_000_000)
            publishers[topic].publish(msg)
            sent[topic] = sent.get(topic, 0) + 1
            executor.spin_once(timeout_sec=0.001)
            time.sleep(0.002)

        send()
        values = _diagnostics(node, executor, 3.0)
    assert sum(v for k, v in sent.items() if k != 'reset') == MESSAGES
    assert launcher.poll() is None, 'the launcher stopped'
    print(f'fuzz: {MESSAGES} messages, {sent}')
    for name, node_values in sorted(values.items()):
        print(name, {k: v for k, v in node_values.items() if 'dropped' in k or k == 'restarts'})
    for role in NODES:
        statuses = [v for name, v in values.items() if name.endswith(role)]
        assert statuses, f'no /diagnostics from {role}: {sorted(values)}'
        for status in statuses:
            assert 'dropped.internal_error' not in status, status
            assert 'restarts' not in status, status  # no node died and came back
            assert int(status.get('dropped.total', 0)) > 0, status  # refusals are counted

    after = _mpjpe(ros_env, sim.bag, tmp_path / 'after', '--no-launch')
    launcher.send_signal(2)
    launcher.wait(timeout=30)
    out = ''.join(output)
    assert launcher.returncode == 0, out[-3000:]
    assert 'restarting it' not in out, out[-3000:]
    print(f'studio-arm MPJPE: fresh graph {fresh:.1f} mm, after the fuzzing {after:.1f} mm')
    assert after <= 1.1 * fresh + 0.5, (fresh, after)
