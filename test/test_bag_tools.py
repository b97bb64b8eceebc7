"""`memo-ros bag info|play|record`: a bag played over DDS and recorded again keeps every byte."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from memo_ros.ros.bagio import BagError
from memo_ros.ros.messages import import_message_type
from memo_ros.ros.pointcloud import CONTOUR_DTYPE, pointcloud_to_array
from memo_ros.tools.bag.info import bag_summary
from memo_ros.tools.bag.play import BagPlayer, PlayOptions

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
START_NS = 1_767_225_600_000_000_000
STEP_NS = 20_000_000
TOPICS = {
    '/cam/image_raw': 'sensor_msgs/msg/Image',
    '/cam/camera_info': 'sensor_msgs/msg/CameraInfo',
    '/memo/joint_states': 'sensor_msgs/msg/JointState',
    '/cam/contours': 'sensor_msgs/msg/PointCloud2',
}


def _header(stamp_ns: int, frame_id: str):
    time = T['builtin_interfaces/msg/Time'](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return T['std_msgs/msg/Header'](stamp=time, frame_id=frame_id)


def _image(stamp_ns: int, seed: int):
    pixels = np.random.default_rng(seed).integers(0, 256, (6, 8), dtype=np.uint8)
    return T['sensor_msgs/msg/Image'](
        header=_header(stamp_ns, 'cam'),
        height=6,
        width=8,
        encoding='mono8',
        is_bigendian=0,
        step=8,
        data=pixels.reshape(-1),
    )


def _camera_info(stamp_ns: int):
    roi = T['sensor_msgs/msg/RegionOfInterest'](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    k = np.array([500.0, 0, 4, 0, 500.0, 3, 0, 0, 1])
    p = np.array([500.0, 0, 4, 0, 0, 500.0, 3, 0, 0, 0, 1, 0])
    return T['sensor_msgs/msg/CameraInfo'](
        header=_header(stamp_ns, 'cam'),
        height=6,
        width=8,
        distortion_model='plumb_bob',
        d=np.zeros(5),
        k=k,
        r=np.eye(3).reshape(-1),
        p=p,
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def _joint_state(stamp_ns: int, knee: float):
    # empty velocity: the case where rclpy's serialize_message pads and rosbags refuses the bytes
    return T['sensor_msgs/msg/JointState'](
        header=_header(stamp_ns, 'world'),
        name=['root_tx', 'knee_l'],
        position=np.array([0.5, knee]),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )


def _contours(stamp_ns: int):
    points = np.zeros(5, CONTOUR_DTYPE)
    points['x'], points['y'] = np.arange(5) * 2.5, 7.0
    points['tx'], points['ty'], points['contour'] = 1.0, 0.0, [0, 0, 1, 1, 1]
    field = T['sensor_msgs/msg/PointField']
    fields = [
        field(
            name=n, offset=CONTOUR_DTYPE.fields[n][1], datatype=7 if n != 'contour' else 6, count=1
        )
        for n in CONTOUR_DTYPE.names
    ]
    return T['sensor_msgs/msg/PointCloud2'](
        header=_header(stamp_ns, 'cam'),
        height=1,
        width=5,
        fields=fields,
        is_bigendian=False,
        point_step=CONTOUR_DTYPE.itemsize,
        row_step=5 * CONTOUR_DTYPE.itemsize,
        data=points.view(np.uint8).copy(),
        is_dense=True,
    )


def write_test_bag(path, storage=StoragePlugin.MCAP) -> dict[str, list[bytes]]:
    """Return a small bag of every kind of message the graph uses.

    The serialized bytes per topic, in order.
    """
    messages = [('/cam/camera_info', _camera_info(START_NS))]
    for i in range(3):
        messages.append(('/cam/image_raw', _image(START_NS + i * STEP_NS, i)))
        messages.append(('/memo/joint_states', _joint_state(START_NS + i * STEP_NS, 0.1 * i)))
    messages.append(('/cam/contours', _contours(START_NS + STEP_NS)))
    expected: dict[str, list[bytes]] = {topic: [] for topic in TOPICS}
    with Writer(path, version=9, storage_plugin=storage) as writer:
        conns = {
            t: writer.add_connection(t, msgtype, typestore=TS) for t, msgtype in TOPICS.items()
        }
        for index, (topic, msg) in enumerate(messages):
            data = bytes(TS.serialize_cdr(msg, TOPICS[topic]))
            writer.write(conns[topic], START_NS + index * STEP_NS, data)
            expected[topic].append(data)
    return expected


def read_bag(path) -> tuple[dict[str, list[bytes]], dict[str, str], dict[str, str]]:
    """Bytes per topic in order, topic types, and the message definitions stored per topic."""
    data: dict[str, list[bytes]] = {}
    with Reader(path) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        msgdefs = {c.topic: c.msgdef.data for c in reader.connections}
        for conn, _, raw in reader.messages():
            data.setdefault(conn.topic, []).append(bytes(raw))
    return data, types, msgdefs


@pytest.fixture
def test_bag(tmp_path):
    path = tmp_path / 'in'
    return path, write_test_bag(path)


def test_play_and_record_keep_every_byte(ros_env, test_bag, tmp_path):
    bag, expected = test_bag
    out = tmp_path / 'out'
    total = sum(len(v) for v in expected.values())
    recorder = ros_env.start(
        'bag', 'record', '-o', out, *TOPICS, '--max-messages', total, '--duration', 25
    )
    played = ros_env.run('bag', 'play', bag, '--wait-for-subscribers', 1, '--wait-timeout', 20)
    assert played.returncode == 0, played.stderr
    _, rec_err = recorder.communicate(timeout=25)
    assert recorder.returncode == 0, rec_err
    assert f'{total} messages written' in rec_err

    got, types, msgdefs = read_bag(out)
    assert types == TOPICS
    assert all(msgdefs[t] for t in TOPICS), 'the mcap must carry the message definitions'
    for topic, payloads in expected.items():
        # Fast DDS delivers payloads across processes padded with zeros to a multiple of 4 bytes
        # (a real `ros2 bag record` stores them so too); everything else is the played bytes
        assert got[topic] == [p + bytes(-len(p) % 4) for p in payloads], topic
        for raw in got[topic]:
            TS.deserialize_cdr(raw, TOPICS[topic])  # strict: no trailing padding
            deserialize_message(raw, import_message_type(TOPICS[topic]))
    joints = deserialize_message(
        got['/memo/joint_states'][2], import_message_type(TOPICS['/memo/joint_states'])
    )
    assert list(joints.name) == ['root_tx', 'knee_l'] and list(joints.velocity) == []
    assert joints.position[1] == pytest.approx(0.2)
    cloud = deserialize_message(
        got['/cam/contours'][0], import_message_type(TOPICS['/cam/contours'])
    )
    assert pointcloud_to_array(cloud)['contour'].tolist() == [0, 0, 1, 1, 1]

    info = ros_env.run('bag', 'info', out)
    assert info.returncode == 0 and 'Storage id:        mcap' in info.stdout


def test_info_counts_types_and_span(ros_env, test_bag):
    bag, expected = test_bag
    result = ros_env.run('bag', 'info', bag)
    assert result.returncode == 0, result.stderr
    assert 'Messages:          8' in result.stdout
    assert (
        'Start:             2026-01-01T00:00:00.000000000Z (1767225600.000000000)' in result.stdout
    )
    assert 'Duration:          0.140000000 s' in result.stdout
    for topic, msgtype in TOPICS.items():
        line = next(line for line in result.stdout.splitlines() if topic + ' ' in line)
        assert msgtype in line and f'Count: {len(expected[topic]):>7}' in line and 'cdr' in line


def test_info_reads_sqlite3_bags(tmp_path):
    write_test_bag(tmp_path / 'db', StoragePlugin.SQLITE3)
    summary = bag_summary(tmp_path / 'db')
    assert summary.storage == 'sqlite3' and summary.message_count == 8
    assert {t.topic: t.count for t in summary.topics}['/cam/image_raw'] == 3


def test_errors_are_one_line(ros_env):
    cases = [
        (('info', '/no/such/bag'), 'no bag at /no/such/bag'),
        (('info', '.'), 'not a rosbag2 directory'),
        (('play', '/no/such/bag'), 'no bag at /no/such/bag'),
    ]
    processes = [(ros_env.start('bag', *args), message) for args, message in cases]
    for process, message in processes:
        _, stderr = process.communicate(timeout=30)
        assert process.returncode != 0 and 'Traceback' not in stderr
        assert stderr.count('\n') == 1 and message in stderr


def test_play_and_record_refuse_bad_requests(ros_env, test_bag):
    bag, _ = test_bag
    tf_bag = bag.parent / 'tf'  # tf2_msgs is in the Jazzy typestore but not installed here
    with Writer(tf_bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/tf', 'tf2_msgs/msg/TFMessage', typestore=TS)
        writer.write(
            conn,
            START_NS,
            bytes(
                TS.serialize_cdr(
                    T['tf2_msgs/msg/TFMessage'](transforms=[]), 'tf2_msgs/msg/TFMessage'
                )
            ),
        )
    mislabelled = bag.parent / 'mislabelled'  # images whose metadata says camera_info
    with Writer(mislabelled, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/cam/image_raw', 'sensor_msgs/msg/CameraInfo', typestore=TS)
        image = bytes(TS.serialize_cdr(_image(START_NS, 0), 'sensor_msgs/msg/Image'))
        writer.write(conn, START_NS, image)
    cases = [
        (('play', tf_bag), "cannot play /tf: unknown message type 'tf2_msgs/msg/TFMessage'"),
        (('play', mislabelled), '/cam/image_raw: its messages are not sensor_msgs/msg/CameraInfo'),
        (('play', bag, '--topics', '/nope'), 'not in the bag: /nope'),
        (('play', bag, '--remap', 'nonsense'), 'bad remap'),
        (('record', '-o', bag, '/x'), 'exists already'),
        (('record', '-o', bag.parent / 'new'), 'name the topics'),
    ]
    processes = [(ros_env.start('bag', *args), message) for args, message in cases]
    for process, message in processes:
        _, stderr = process.communicate(timeout=30)
        assert process.returncode == 2 and 'Traceback' not in stderr, stderr
        assert message in stderr


def test_unreadable_bag_is_a_clear_error(tmp_path):
    (tmp_path / 'broken').mkdir()
    (tmp_path / 'broken' / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information: {version: 9}\n'
    )
    with pytest.raises(BagError, match='cannot read bag'):
        bag_summary(tmp_path / 'broken')


def test_player_offset_topics_remap_and_hooks(ros_env, test_bag):
    bag, expected = test_bag
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_env.domain_id)
    node = rclpy.create_node('player_test', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        seen = []
        options = PlayOptions(
            rate=0.0,
            start_offset=0.05,
            topics=['/cam/image_raw', 'memo/joint_states'],
            remap={'/cam/image_raw': '/other/image'},
        )
        with BagPlayer(node, bag, options, before_publish=seen.append) as player:
            assert player.topics == {
                '/other/image': TOPICS['/cam/image_raw'],
                '/memo/joint_states': TOPICS['/memo/joint_states'],
            }
            assert player.play(threading.Event()) == len(seen)
        # log times are START + index * STEP: the offset skips the first three messages of the bag
        assert [m.log_time_ns for m in seen] == [START_NS + i * STEP_NS for i in range(3, 7)]
        assert [m.topic for m in seen] == [
            '/other/image',
            '/memo/joint_states',
            '/other/image',
            '/memo/joint_states',
        ]
        assert [m.data for m in seen if m.bag_topic == '/cam/image_raw'] == expected[
            '/cam/image_raw'
        ][1:]
        with pytest.raises(BagError, match='rate must be positive'):
            BagPlayer(node, bag, PlayOptions(rate=-1.0))
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
