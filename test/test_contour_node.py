"""contour_node as its own process over real DDS.

a bag played in, contours recorded out; bad input survived.
"""

from __future__ import annotations

import subprocess
import time

from conftest import play_when_matched, wait_until_recording
import cv2
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

from memo_ros.core.latency.decimation import Decimation
from memo_ros.ros.bagio import read_messages, stamp_to_ns
from memo_ros.ros.dds import ros_session
from memo_ros.ros.decimation_messages import DECIMATION_QOS, DECIMATION_TOPIC, decimation_message
from memo_ros.ros.pointcloud import pointcloud_to_array
from memo_ros.tools.simulate import simulate


def _diagnostics_of(node, hardware_id: str) -> dict[str, str]:
    """Subscribe ``node`` to /diagnostics; return a dict of ``hardware_id``'s latest values."""
    values: dict[str, str] = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id == hardware_id:
                values.update({kv.key: kv.value for kv in status.values})

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    return values


def _spinner(executor, period: float):
    """Return spin(seconds, until): spin ``executor`` for that long or until ``until()`` holds."""

    def spin(seconds: float, until=lambda: False) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            executor.spin_once(timeout_sec=period)

    return spin


def _start_node(ros_env, camera: str, *params: str) -> subprocess.Popen:
    return ros_env.start_node(
        'contour_node', '-r', f'__ns:=/{camera}', *[a for p in params for a in ('-p', p)]
    )


def test_node_process_turns_a_played_bag_into_contours(ros_env, tmp_path):
    bag = simulate('street-walk', tmp_path / 'street', frames=12, width=320, height=240).bag
    node = _start_node(ros_env, 'cam_street', 'reliable_images:=true', 'background_frames:=6')
    out = tmp_path / 'contours'
    inputs = ['/cam_street/image_raw', '/cam_street/camera_info']
    outputs = ['/cam_street/contours', '/cam_street/person_box', '/cam_street/edges']
    recorder = ros_env.start(
        'bag', 'record', '-o', out, *outputs, '--idle-timeout', 4, '--duration', 60
    )
    wait_until_recording(recorder, outputs)
    assert play_when_matched(ros_env.domain_id, bag, inputs, outputs, rate=2) == 24
    recorder.communicate(timeout=60)
    assert node.poll() is None, 'the node must keep running'
    images = [
        stamp_to_ns(m.message.header.stamp) for m in read_messages(bag, ['/cam_street/image_raw'])
    ]
    contours = list(read_messages(out, ['/cam_street/contours']))
    # every frame, header copied; only the very first may precede its camera_info on another topic
    stamps = [stamp_to_ns(m.message.header.stamp) for m in contours]
    assert stamps in (images, images[1:])
    tables = {stamp: pointcloud_to_array(m.message) for stamp, m in zip(stamps, contours)}
    assert all(len(tables[s]) == 0 for s in images[1:5])  # learning the background
    assert all(len(tables[s]) > 50 for s in images[7:])  # the pedestrian's outline
    assert np.allclose(
        np.hypot(tables[images[-1]]['tx'], tables[images[-1]]['ty']), 1.0, atol=1e-4
    )
    boxes = [m.message for m in read_messages(out, ['/cam_street/person_box'])]
    assert len(boxes[-1].polygon.points) == 4
    # the recorder subscribes to edges (edges: auto): edge lines with every frame's contours
    edges = {
        stamp_to_ns(m.message.header.stamp): pointcloud_to_array(m.message)
        for m in read_messages(out, ['/cam_street/edges'])
    }
    assert sorted(edges) == stamps
    assert all(len(edges[s]) > 0 for s in images[7:])


def test_edge_lines_are_wanted_in_auto_only_for_a_subscriber():
    from memo_ros.nodes.contour_node import PARAMS, edges_wanted

    assert [edges_wanted('auto', n) for n in (0, 1, 3)] == [False, True, True]
    assert [edges_wanted('always', n) for n in (0, 1)] == [True, True]
    assert [edges_wanted('never', n) for n in (0, 1)] == [False, False]
    with pytest.raises(ValueError, match='sometimes'):
        edges_wanted('sometimes', 1)
    (param,) = [p for p in PARAMS if p.name == 'edges']
    assert param.default == 'auto' and param.choices == ('auto', 'always', 'never')
    assert param.check('sometimes') and param.check('always') is None


def test_bad_images_are_counted_with_their_reason_and_the_node_keeps_running(ros_env):
    node_process = _start_node(ros_env, 'cam_bad', 'background_frames:=1')
    with ros_session('bad_input_feeder', ros_env.domain_id) as (node, executor):
        image_pub = node.create_publisher(Image, '/cam_bad/image_raw', 10)
        info_pub = node.create_publisher(CameraInfo, '/cam_bad/camera_info', 10)
        reports = []
        node.create_subscription(DiagnosticArray, '/diagnostics', reports.append, 10)

        def image(encoding='mono8', width=32, height=24, step=None, size=None, sec=1):
            msg = Image(encoding=encoding, width=width, height=height, step=step or width)
            msg.header.stamp.sec = sec
            msg.data = bytes(size if size is not None else msg.step * height)
            return msg

        deadline = time.monotonic() + 15
        while image_pub.get_subscription_count() < 1 or info_pub.get_subscription_count() < 1:
            executor.spin_once(timeout_sec=0.1)
            assert time.monotonic() < deadline, 'contour_node did not appear'
        values: dict[str, str] = {}

        def spin_until(keys, publish=None, timeout=15.0):
            deadline = time.monotonic() + timeout
            while not set(keys) <= set(values) and time.monotonic() < deadline:
                if publish is not None:
                    publish()
                executor.spin_once(timeout_sec=0.3)
                for report in reports:
                    for status in report.status:
                        if status.hardware_id == 'cam_bad':
                            values.update({kv.key: kv.value for kv in status.values})
            assert set(keys) <= set(values), values

        # before any camera_info the image is processed all the same (repeated until the
        # subscription matched;
        # the repeats share a stamp and are dropped as duplicates)
        spin_until(
            ['no_camera_info', 'processed'], publish=lambda: image_pub.publish(image(sec=1))
        )
        info_pub.publish(CameraInfo(width=32, height=24, distortion_model='plumb_bob'))
        # a report published after the last early image arrived (reports come once a second)
        time.sleep(1.2)
        reports.clear()
        values.clear()
        spin_until(['frames_in'])
        # the node's side of each match: this feeder publishes its inputs, nobody takes its outputs
        assert values['publishers./cam_bad/image_raw'] == '1', values
        assert values['publishers./cam_bad/camera_info'] == '1', values
        assert values['subscribers./cam_bad/contours'] == '0', values
        before = int(values['frames_in'])
        processed_before = int(values['processed'])
        dropped_before = int(values.get('dropped.total', 0))
        for msg in [
            image('yuv422', sec=2),
            image(step=10, sec=3),
            image(size=5, sec=4),
            image(width=16, step=16, sec=5),
            image(sec=6),
            image(sec=7),
            image(sec=3),  # one stale image: dropped, the history kept
            image(sec=8),
            image(sec=4),  # then three in a row back in time (a bag loop): the history reset
            image(sec=5),
            image(sec=6),
        ]:
            image_pub.publish(msg)
            time.sleep(0.1)
        spin_until(
            [
                'dropped.unsupported_encoding',
                'dropped.bad_step',
                'dropped.bad_data_length',
                'dropped.size_mismatch',
                'dropped.out_of_order',
                'time_jump_resets',
            ]
        )
        time.sleep(1.2)
        reports.clear()
        spin_until(['processed'])
        assert (
            int(values['processed']) == processed_before + 4
            and int(values['frames_in']) == before + 11
        )
        assert int(values['dropped.out_of_order']) == 3  # sec 3, then sec 4 and 5 before the reset
        assert int(values['dropped.total']) == dropped_before + 7
        assert int(values['time_jump_resets']) == 1
        assert node_process.poll() is None


def _background_frame(pixels: np.ndarray, sec: int) -> Image:
    msg = Image(encoding='mono8', width=64, height=48, step=64, data=pixels.tobytes())
    msg.header.stamp.sec = sec
    return msg


def _background_info(sec: int) -> CameraInfo:
    msg = CameraInfo(width=64, height=48, distortion_model='plumb_bob')
    msg.header.stamp.sec = sec
    return msg


def _run_background_node(
    ros_env,
    params,
    frames,
    first_sec: int,
    stamps: list[int] | None = None,
    before=(),
    decimation: Decimation | None = None,
) -> tuple[dict, list]:
    """Start a 64x48 contour_node, feed it frames (None: a lost image) with a camera_info each.

    Stamped ``first_sec`` + k, or ``stamps`` (seconds); the messages ``before`` (Image or
    CameraInfo) go first, and ``decimation`` is announced before them as the tracker would.
    Stop it; return its /diagnostics values and its contour clouds.
    """
    stamps = stamps or [first_sec + k for k in range(len(frames))]
    process = _start_node(ros_env, 'cam_bg', *params)
    values: dict[str, str] = {}
    contours = []
    try:
        with ros_session('background_feeder', ros_env.domain_id) as (node, executor):
            image_pub = node.create_publisher(Image, '/cam_bg/image_raw', 10)
            info_pub = node.create_publisher(CameraInfo, '/cam_bg/camera_info', 10)
            node.create_subscription(PointCloud2, '/cam_bg/contours', contours.append, 100)

            values = _diagnostics_of(node, 'cam_bg')
            deadline = time.monotonic() + 15
            while image_pub.get_subscription_count() < 1 or info_pub.get_subscription_count() < 1:
                executor.spin_once(timeout_sec=0.1)
                assert time.monotonic() < deadline, 'contour_node did not appear'
            if decimation is not None:
                node.create_publisher(Header, DECIMATION_TOPIC, DECIMATION_QOS).publish(
                    decimation_message(decimation)
                )
            time.sleep(1.0)
            for msg in before:
                (image_pub if isinstance(msg, Image) else info_pub).publish(msg)
                executor.spin_once(timeout_sec=0.15)
            for k, pixels in enumerate(frames):
                info_pub.publish(_background_info(stamps[k]))
                if pixels is not None:
                    image_pub.publish(_background_frame(pixels, stamps[k]))
                end = time.monotonic() + 0.15
                while time.monotonic() < end:
                    executor.spin_once(timeout_sec=0.05)
            end = time.monotonic() + 15
            while (  # until every image sent is processed, refused as out of order or shed
                int(values.get('processed', 0))
                + int(values.get('dropped.out_of_order', 0))
                + int(values.get('dropped.shed', 0))
                < sum(f is not None for f in frames)
                and time.monotonic() < end
            ):
                executor.spin_once(timeout_sec=0.1)
            time.sleep(1.1)
            end = time.monotonic() + 2
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.1)
    finally:
        process.send_signal(2)
        process.communicate(timeout=15)
    return values, contours


def _scene() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    empty = rng.integers(90, 110, (48, 64), dtype=np.uint8)
    person = empty.copy()
    person[10:40, 20:34] = 200
    return empty, person


def test_lost_images_are_counted_and_a_restarted_node_reuses_its_saved_background(
    ros_env, tmp_path
):
    background_file = tmp_path / 'cam_bg_background.png'
    params = ('background_frames:=3', f'background_file:={background_file}', 'min_region_area:=20')
    empty, person = _scene()

    # first run: learns the empty scene, saves it; two images never arrive (their camera_info does)
    values, contours = _run_background_node(
        ros_env, params, [empty, empty, empty, person, None, person, None, person], 1
    )
    assert background_file.is_file()
    assert int(values['dropped.image_lost']) == 2, values
    assert int(values['processed']) == 6 and int(values['warming_up']) == 3, values
    assert len(pointcloud_to_array(contours[-1])) > 20
    # restarted with the person in view: the saved background is used, no learning, contours at
    # once
    values, contours = _run_background_node(ros_env, params, [person, person], 20)
    assert 'warming_up' not in values, values
    assert len(contours) == 2 and all(len(pointcloud_to_array(c)) > 20 for c in contours)


def test_a_background_with_the_person_in_it_is_neither_saved_nor_loaded(ros_env, tmp_path):
    background_file = tmp_path / 'cam_bg_background.png'
    params = ('background_frames:=3', f'background_file:={background_file}', 'min_region_area:=20')
    empty, person = _scene()
    moved = empty.copy()
    moved[10:40, 30:44] = 200  # the person stepped aside while the background was learnt

    # learnt while the person stood in view and moved: used, not saved
    values, _ = _run_background_node(ros_env, params, [person, moved, person, person], 1)
    assert not background_file.exists()
    assert int(values['background_not_saved']) == 1, values
    assert int(values['processed']) == 4 and int(values['warming_up']) == 3, values

    # a picture with the person in it, left where the background would be: refused, learnt anew
    cv2.imwrite(str(background_file), person)
    values, _ = _run_background_node(ros_env, params, [empty, empty, empty, person], 20)
    assert int(values['background_refused']) == 1, values
    assert int(values['warming_up']) == 3, values
    assert background_file.with_name(background_file.name + '.yaml').is_file()  # relearnt, saved


def test_edge_lines_follow_a_subscriber_that_comes_late_and_the_edges_parameter(ros_env):
    empty, person = _scene()
    process = _start_node(ros_env, 'cam_edge', 'background_frames:=3', 'min_region_area:=20')
    values: dict[str, str] = {}
    edges: dict[int, np.ndarray] = {}
    try:
        with ros_session('edges_feeder', ros_env.domain_id) as (node, executor):
            image_pub = node.create_publisher(Image, '/cam_edge/image_raw', 10)
            info_pub = node.create_publisher(CameraInfo, '/cam_edge/camera_info', 10)

            values = _diagnostics_of(node, 'cam_edge')

            spin = _spinner(executor, 0.05)

            deadline = time.monotonic() + 15
            while image_pub.get_subscription_count() < 1 or info_pub.get_subscription_count() < 1:
                spin(0.1)
                assert time.monotonic() < deadline, 'contour_node did not appear'
            spin(1.0)
            sent: list[int] = []

            def feed(pixels: np.ndarray) -> None:
                sec = len(sent) + 1
                info_pub.publish(_background_info(sec))
                image_pub.publish(_background_frame(pixels, sec))
                sent.append(sec * 1_000_000_000)
                spin(0.15)

            # nobody subscribes to edges: none computed, frames counted as ever
            for pixels in (empty, empty, empty, person, person):
                feed(pixels)
            spin(
                10.0,
                lambda: (
                    int(values.get('processed', 0)) == 5
                    and values.get('contour_points', '0') != '0'
                ),
            )
            assert values.get('edge_lines') == 'off (no subscriber)', values
            # a subscriber comes: from the first frame its subscription is matched on, every frame
            # brings its edge lines
            node.create_subscription(
                PointCloud2,
                '/cam_edge/edges',
                lambda m: edges.setdefault(stamp_to_ns(m.header.stamp), pointcloud_to_array(m)),
                100,
            )
            deadline = time.monotonic() + 15
            while not edges:
                feed(person)
                assert time.monotonic() < deadline, 'no edge lines for the new subscriber'
            first = min(edges)
            later = len(sent)
            for _ in range(3):
                feed(person)
            spin(10.0, lambda: {s for s in sent if s >= first} <= set(edges))
            assert set(edges) == {s for s in sent if s >= first}
            assert all(len(edges[s]) >= 4 for s in sent[later:])  # the person's four sides
            spin(2.5)  # a report after the last frame
            assert values['edge_lines'].isdigit() and int(values['processed']) == len(sent), values
            # edges: never, set at runtime: nothing on edges for the subscriber from the next
            # frame on, and the learnt background is kept (contours at once, no learning anew)
            client = node.create_client(SetParameters, '/cam_edge/contour_node/set_parameters')
            assert client.wait_for_service(timeout_sec=10)
            future = client.call_async(
                SetParameters.Request(
                    parameters=[Parameter('edges', value='never').to_parameter_msg()]
                )
            )
            executor.spin_until_future_complete(future, timeout_sec=10)
            assert future.result().results[0].successful
            contours: dict[int, np.ndarray] = {}
            node.create_subscription(
                PointCloud2,
                '/cam_edge/contours',
                lambda m: contours.setdefault(stamp_to_ns(m.header.stamp), pointcloud_to_array(m)),
                100,
            )
            spin(1.0)
            silent = len(sent)
            deadline = time.monotonic() + 15
            while not contours:
                feed(person)
                assert time.monotonic() < deadline, 'no contours after the switch'
            for _ in range(2):
                feed(person)
            spin(10.0, lambda: set(sent[-2:]) <= set(contours))
            spin(2.5)
            assert all(len(contours[s]) > 20 for s in sent[-2:])
            assert not set(edges) & set(sent[silent:]), 'edge lines after edges:=never'
            assert values['edge_lines'] == 'off (edges: never)', values
            assert int(values['warming_up']) == 3 and 'reconfigured' not in values, values
    finally:
        process.send_signal(2)
        process.communicate(timeout=15)

    # edges: always: computed with nobody listening
    params = ('background_frames:=3', 'min_region_area:=20')
    values, _ = _run_background_node(
        ros_env, (*params, 'edges:=always'), [empty, empty, empty, person], 1
    )
    assert int(values['edge_lines']) >= 4 and int(values['processed']) == 4, values


def test_one_image_stamped_in_the_past_is_counted_and_changes_no_contour(ros_env):
    params = ('background_frames:=3', 'min_region_area:=20')
    empty, _ = _scene()
    walking = []
    for k in range(5):  # the person moves, so every frame's contour is its own
        frame = empty.copy()
        frame[10:40, 12 + 4 * k : 26 + 4 * k] = 200
        walking.append(frame)
    plain = [empty, empty, empty, *walking]
    _, expected = _run_background_node(ros_env, params, plain, 1)
    # the same, with an image of the person stamped 4 s back arriving after the second person frame
    stale = [empty, empty, empty, walking[0], walking[1], walking[3], *walking[2:]]
    stamps = [1, 2, 3, 4, 5, 1, 6, 7, 8]
    values, seen = _run_background_node(ros_env, params, stale, 1, stamps)
    assert int(values['dropped.out_of_order']) == 1 and 'time_jump_resets' not in values, values
    assert int(values['processed']) == len(plain), values
    clouds = [pointcloud_to_array(c) for c in seen]
    wanted = [pointcloud_to_array(c) for c in expected]
    assert len(clouds) == len(wanted) == len(plain)  # one cloud per processed image
    for got, want in zip(clouds[-len(walking) :], wanted[-len(walking) :]):
        assert len(got) > 20 and np.array_equal(got, want)


def test_a_refused_image_stamped_years_ahead_leaves_every_later_frame_processed(ros_env):
    # the fuzz test's good bag after the fuzzing: a bad image stamped in the future must not make
    # every later frame look past (its camera_info counted lost at once, its image ignored late)
    empty, person = _scene()
    future = 1_900_000_000
    bad = _background_frame(empty, future)
    bad.encoding = 'yuv422'  # refused: unsupported_encoding
    frames = [empty, empty, empty, person, person]
    values, contours = _run_background_node(
        ros_env, ('background_frames:=3', 'min_region_area:=20'), frames, 1,
        before=[_background_info(future), bad],
    )  # fmt: skip
    assert int(values['dropped.unsupported_encoding']) == 1, values
    assert int(values['processed']) == len(frames) and 'late_images' not in values, values
    assert 'dropped.image_lost' not in values, values  # the bad image answered its camera_info
    assert len(contours) == len(frames)


def test_a_background_track_that_is_not_a_bag_stops_the_node_with_one_line(ros_env, tmp_path):
    from memo_ros.core.formats.studio import Studio

    sim = simulate('studio-arm', tmp_path / 'arm', frames=2, width=160, height=120)
    studio = Studio.load(sim.studio)  # the studio's node entries win over -p: set them there
    studio.node_parameters['contour_node'].update(
        segmenter='sequence',
        background_bag=str(sim.bag),
        background_track=str(tmp_path / 'no_such_track'),
    )
    studio.save(tmp_path / 'studio.yaml')
    node = ros_env.start_node(
        'contour_node', '-r', '__ns:=/cam_front', '--params-file', tmp_path / 'studio.yaml'
    )
    out, _ = node.communicate(timeout=60)
    assert node.returncode == 2, out
    lines = [line for line in out.splitlines() if 'no_such_track' in line]
    assert len(lines) == 1 and 'no bag at' in lines[0] and 'Traceback' not in out, out


def test_with_roi_wait_an_image_waits_for_the_tracked_body_of_the_image_before_it(
    ros_env, tmp_path
):
    # bag replay: whether the tracker's /memo/markers of frame t reach the node before the images
    # of frame
    # t + 1 must not decide the tracked region; with roi_wait the image waits for them (at most
    # roi_wait)
    from visualization_msgs.msg import MarkerArray

    from memo_ros.core.formats.studio import Studio
    from memo_ros.core.multiview.motion import coordinates_from_names
    from memo_ros.ros.body_messages import marker_array_message

    sim = simulate('studio-arm', tmp_path / 'arm', frames=4, width=160, height=120)
    studio = Studio.load(sim.studio)  # the studio's node entries win over -p: set them there
    studio.node_parameters['contour_node'].update(
        keep_regions='tracked', background_frames=1, roi_wait=1.5
    )
    studio.save(tmp_path / 'studio.yaml')
    images = [m.message for m in read_messages(sim.bag, ['/cam_front/image_raw'])]
    body = studio.body
    rotations, origins = body.forward_kinematics(
        coordinates_from_names(body, list(studio.initial_pose), list(studio.initial_pose.values()))
    )
    process = ros_env.start_node(
        'contour_node', '-r', '__ns:=/cam_front', '--params-file', tmp_path / 'studio.yaml'
    )
    try:
        with ros_session('roi_wait_feeder', ros_env.domain_id) as (node, executor):
            image_pub = node.create_publisher(Image, '/cam_front/image_raw', 10)
            marker_pub = node.create_publisher(MarkerArray, '/memo/markers', 10)
            arrived: dict[int, float] = {}
            node.create_subscription(
                PointCloud2,
                '/cam_front/contours',
                lambda m: arrived.setdefault(stamp_to_ns(m.header.stamp), time.monotonic()),
                10,
            )
            values = _diagnostics_of(node, 'cam_front')

            spin = _spinner(executor, 0.02)

            deadline = time.monotonic() + 20
            while (
                image_pub.get_subscription_count() < 1 or marker_pub.get_subscription_count() < 1
            ):
                spin(0.1)
                assert time.monotonic() < deadline, 'contour_node did not appear'
            spin(1.0)
            stamps = [stamp_to_ns(m.header.stamp) for m in images]

            def send_image(k: int) -> float:
                image_pub.publish(images[k])
                return time.monotonic()

            def send_markers(k: int) -> float:
                marker_pub.publish(marker_array_message(stamps[k], body, rotations, origins))
                return time.monotonic()

            # before any tracked body the node does not wait: no tracker may be running
            sent = send_image(0)
            spin(5.0, lambda: stamps[0] in arrived)
            assert arrived[stamps[0]] - sent < 1.0
            send_markers(0)
            spin(0.3)
            sent = send_image(1)  # the body of image 0 is in: no wait
            spin(5.0, lambda: stamps[1] in arrived)
            assert arrived[stamps[1]] - sent < 1.0
            send_image(2)  # the body of image 1 is not: it waits ...
            spin(0.7)
            assert stamps[2] not in arrived
            told = send_markers(1)  # ... until it comes
            spin(5.0, lambda: stamps[2] in arrived)
            assert 0 <= arrived[stamps[2]] - told < 0.5
            sent = send_image(3)  # the body of image 2 never comes: roi_wait, then on
            spin(5.0, lambda: stamps[3] in arrived)
            assert 1.4 < arrived[stamps[3]] - sent < 3.0
            spin(3.0, lambda: 'roi_wait_timeouts' in values)
            assert values.get('roi_wait_timeouts') == '1' and int(values['processed']) == 4, values
            assert process.poll() is None
    finally:
        process.send_signal(2)
        process.communicate(timeout=15)


def test_every_frame_of_a_300_hz_burst_is_processed_or_counted_once(ros_env):
    """300 VGA frames at 300 Hz: far more than a node takes, from a publisher whose queue drops.

    Each is processed, or counted as image_lost (its camera_info came) or frames_missing (a gap
    in the stamps of both streams).  Only a last frame of which nothing came cannot be known.
    """
    frames = 300
    process = _start_node(ros_env, 'cam_burst', 'background_frames:=3')
    values: dict[str, str] = {}
    try:
        with ros_session('burst', ros_env.domain_id) as (node, executor):
            image_pub = node.create_publisher(Image, '/cam_burst/image_raw', 10)
            info_pub = node.create_publisher(CameraInfo, '/cam_burst/camera_info', 10)

            values = _diagnostics_of(node, 'cam_burst')
            deadline = time.monotonic() + 15
            while image_pub.get_subscription_count() < 1 or info_pub.get_subscription_count() < 1:
                executor.spin_once(timeout_sec=0.1)
                assert time.monotonic() < deadline, 'contour_node did not appear'
            time.sleep(1.0)
            empty = np.random.default_rng(0).integers(90, 110, (480, 640), dtype=np.uint8)
            start = time.monotonic()
            for k in range(frames):
                pixels = empty.copy()
                pixels[100:300, 200 + k % 100 : 260 + k % 100] = 200
                image = Image(encoding='mono8', width=640, height=480, step=640)
                image.data = pixels.tobytes()
                info = CameraInfo(width=640, height=480, distortion_model='plumb_bob')
                info.k = [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0]
                info.d = [0.0] * 5
                for msg in (image, info):
                    msg.header.stamp.sec = 100 + k // 300
                    msg.header.stamp.nanosec = (k % 300) * 3_333_333
                info_pub.publish(info)
                image_pub.publish(image)
                time.sleep(max(start + (k + 1) / 300 - time.monotonic(), 0.0))
            end = time.monotonic() + 8  # the lost-image timer (2 s) and two diagnostics periods
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.1)
    finally:
        process.send_signal(2)
        process.communicate(timeout=15)
    processed, dropped = int(values['processed']), int(values.get('dropped.total', 0))
    print(f'{frames} frames at 300 Hz: {processed} processed, dropped {values}')
    assert dropped > 0, values  # the burst is meant to overrun the node
    assert frames - 1 <= processed + dropped <= frames, values


def test_images_the_decimation_leaves_out_are_counted_shed_and_not_segmented(ros_env):
    """Under the live latency policy a contour node keeps exactly the frames the tracker keeps.

    From the announced stamp on, one in ``every``, the others counted shed (no contours, no
    image_lost): the same stamps in every node, since each applies the same announcement.
    """
    params = ('background_frames:=3', 'min_region_area:=20')
    empty, _ = _scene()
    frames = [empty] * 3
    for k in range(7):
        frame = empty.copy()
        frame[10:40, 12 + 4 * k : 26 + 4 * k] = 200
        frames.append(frame)
    decimation = Decimation(from_ns=5 * 10**9, every=2, period_ns=10**9, origin_ns=4 * 10**9)
    values, seen = _run_background_node(ros_env, params, frames, 1, decimation=decimation)
    kept = [
        s for s in range(1, 11) if decimation.from_ns > s * 10**9 or decimation.keeps(s * 10**9)
    ]
    assert kept == [1, 2, 3, 4, 6, 8, 10]
    assert [c.header.stamp.sec for c in seen] == kept
    assert int(values['processed']) == len(kept), values
    assert int(values['dropped.shed']) == 3, values
    assert not any(k.startswith(('dropped.image_lost', 'dropped.frames_missing')) for k in values)
    assert values['decimation'] == '2'
