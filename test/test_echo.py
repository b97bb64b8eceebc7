"""`memo-ros echo` over DDS, the YAML/CSV renderers, and the PointCloud2 <-> numpy helpers."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image, JointState, PointCloud2, PointField
from std_msgs.msg import Header
import yaml

from memo_ros.ros.messages import flatten_message, message_to_dict, message_to_yaml
from memo_ros.ros.pointcloud import (
    CONTOUR_DTYPE,
    array_to_pointcloud,
    dtype_from_fields,
    pointcloud_to_array,
)

NAMES = ['root_tx', 'knee_l', 'gait_phase']
POSITIONS = [0.5, -0.25, 0.75]
POINTS = 25


def joint_state() -> JointState:
    msg = JointState(name=NAMES, position=POSITIONS)
    msg.header.frame_id = 'world'
    msg.header.stamp.sec = 12
    return msg


def contour_table(n: int = POINTS) -> np.ndarray:
    table = np.zeros(n, CONTOUR_DTYPE)
    table['x'], table['y'] = np.arange(n) * 1.5, np.arange(n) * 2.0
    table['tx'], table['ty'], table['contour'] = 0.6, 0.8, np.arange(n) // 10
    return table


def contour_cloud() -> PointCloud2:
    header = Header(frame_id='cam_front_optical')
    header.stamp.sec = 12
    return array_to_pointcloud(contour_table(), header)


# ----------------------------------------------------------------------------- point clouds
# without DDS


def test_dtype_covers_every_pointfield_type_with_padding_and_counts():
    names = ['i8', 'u8', 'i16', 'u16', 'i32', 'u32', 'f32', 'f64']
    fields, offset = [], 0
    for datatype, name in enumerate(names, start=1):
        fields.append(
            PointField(
                name=name, offset=offset, datatype=datatype, count=2 if name == 'u16' else 1
            )
        )
        offset += 8 if name != 'u16' else 12
    dtype = dtype_from_fields(fields, point_step=offset + 4)
    assert dtype.itemsize == offset + 4
    assert [dtype.fields[n][0].base.str for n in names] == [
        '|i1',
        '|u1',
        '<i2',
        '<u2',
        '<i4',
        '<u4',
        '<f4',
        '<f8',
    ]
    assert dtype.fields['u16'][0].shape == (2,)
    assert [dtype.fields[n][1] for n in names] == [f.offset for f in fields]


def test_dtype_rejects_bad_fields():
    with pytest.raises(ValueError, match='unknown datatype'):
        dtype_from_fields([PointField(name='x', offset=0, datatype=9, count=1)], 4)
    with pytest.raises(ValueError, match='beyond point_step'):
        dtype_from_fields(
            [PointField(name='x', offset=2, datatype=PointField.FLOAT32, count=1)], 4
        )


def test_contour_cloud_round_trip():
    table = contour_table()
    msg = contour_cloud()
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, POINTS, 20, 20 * POINTS)
    assert not msg.is_bigendian and msg.is_dense
    assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [
        ('x', 0, PointField.FLOAT32),
        ('y', 4, PointField.FLOAT32),
        ('tx', 8, PointField.FLOAT32),
        ('ty', 12, PointField.FLOAT32),
        ('contour', 16, PointField.UINT32),
    ]
    again = pointcloud_to_array(deserialize_message(serialize_message(msg), PointCloud2))
    assert again.dtype == CONTOUR_DTYPE and np.array_equal(again, table)


def test_big_endian_organized_cloud_with_row_padding():
    dtype = np.dtype(
        {'names': ['z', 'ring'], 'formats': ['>f8', '>u2'], 'offsets': [0, 8], 'itemsize': 12}
    )
    points = np.zeros((2, 3), dtype)
    points['z'] = [[1, 2, 3], [4, 5, np.nan]]
    points['ring'] = [[7, 8, 9], [10, 11, 12]]
    row_step = 3 * 12 + 4
    data = b''.join(points[row].tobytes() + b'\xff' * 4 for row in range(2))
    fields = [
        PointField(name='z', offset=0, datatype=PointField.FLOAT64, count=1),
        PointField(name='ring', offset=8, datatype=PointField.UINT16, count=1),
    ]
    msg = PointCloud2(
        height=2,
        width=3,
        fields=fields,
        is_bigendian=True,
        point_step=12,
        row_step=row_step,
        data=data,
        is_dense=False,
    )
    read = pointcloud_to_array(msg)
    assert read['ring'].tolist() == [7, 8, 9, 10, 11, 12]
    assert np.array_equal(read['z'], points['z'].reshape(-1), equal_nan=True)
    written = array_to_pointcloud(read)
    assert not written.is_bigendian and not written.is_dense and written.point_step == 12
    assert np.array_equal(pointcloud_to_array(written)['z'], read['z'], equal_nan=True)


# ----------------------------------------------------------------------------- YAML and CSV
# without DDS


def test_yaml_is_valid_and_matches_the_fields():
    msg = joint_state()
    text = message_to_yaml(msg)
    assert 'position: [0.5, -0.25, 0.75]' in text and 'velocity: []' in text
    assert yaml.safe_load(text) == message_to_dict(msg)


def test_yaml_abbreviates_long_data_and_tables_clouds():
    image = Image(height=10, width=10, encoding='mono8', step=10, data=bytes(range(100)))
    assert "data: '<uint8[100]: 0, 1, 2, 3, 4, 5, 6, 7, ...>'" in message_to_yaml(image)
    assert yaml.safe_load(message_to_yaml(image, truncate_length=None))['data'] == list(range(100))
    doc = yaml.safe_load(message_to_yaml(contour_cloud(), max_rows=3))
    rows = doc['points'].splitlines()
    assert rows[0].split() == ['x', 'y', 'tx', 'ty', 'contour']
    assert rows[2].split() == ['1.5', '2.0', '0.6', '0.8', '0']
    assert rows[-1] == f'... {POINTS - 3} more points ({POINTS} in all)'


def test_flatten_names_leaves():
    flat = flatten_message(joint_state())
    assert (
        flat['header.stamp.sec'] == 12
        and flat['name[2]'] == 'gait_phase'
        and flat['position[1]'] == -0.25
    )
    assert not any(key.startswith('velocity') for key in flat)


# ----------------------------------------------------------------------------- echo over DDS


@pytest.fixture
def publishing(ros_env):
    """Return an in-test node publishing a JointState and a contour cloud at 10 Hz."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_env.domain_id)
    node = rclpy.create_node('echo_test_publisher', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    joints = node.create_publisher(JointState, '/memo/joint_states', 10)
    contours = node.create_publisher(PointCloud2, '/cam_front/contours', 10)
    node.create_timer(
        0.1, lambda: (joints.publish(joint_state()), contours.publish(contour_cloud()))
    )
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield ros_env
    finally:
        executor.shutdown()
        thread.join(timeout=5)
        node.destroy_node()
        context.try_shutdown()


def test_echo_yaml_and_csv(publishing):
    runs = {
        'yaml': publishing.start('echo', '/memo/joint_states', '--once', '--timeout', 20),
        'cloud': publishing.start('echo', 'cam_front/contours', '--once', '--timeout', 20),
        'csv': publishing.start(
            'echo', '/memo/joint_states', '--csv', '--count', 2, '--timeout', 20
        ),
        'cloud_csv': publishing.start(
            'echo', '/cam_front/contours', '--csv', '--once', '--timeout', 20
        ),
    }
    out = {}
    for name, process in runs.items():
        stdout, stderr = process.communicate(timeout=30)
        assert process.returncode == 0, f'{name}: {stderr}'
        out[name] = stdout

    docs = [d for d in yaml.safe_load_all(out['yaml']) if d is not None]
    assert len(docs) == 1 and out['yaml'].endswith('---\n')
    assert (
        docs[0]['name'] == NAMES and docs[0]['position'] == POSITIONS and docs[0]['velocity'] == []
    )
    assert docs[0]['header'] == {'stamp': {'sec': 12, 'nanosec': 0}, 'frame_id': 'world'}

    cloud = yaml.safe_load(out['cloud'].split('---')[0])
    assert cloud['width'] == POINTS and cloud['data'].startswith(f'<uint8[{20 * POINTS}]')
    rows = cloud['points'].splitlines()
    assert rows[0].split() == ['x', 'y', 'tx', 'ty', 'contour'] and len(rows) == 1 + 20 + 1
    assert rows[11].split() == ['15.0', '20.0', '0.6', '0.8', '1']

    lines = out['csv'].splitlines()
    assert (
        lines[0]
        == 'header.stamp.sec,header.stamp.nanosec,header.frame_id,name[0],name[1],name[2],'
        'position[0],position[1],position[2]'
    )
    assert lines[1:] == ['12,0,world,root_tx,knee_l,gait_phase,0.5,-0.25,0.75'] * 2

    lines = out['cloud_csv'].splitlines()
    assert (
        lines[0] == 'header.stamp.sec,header.stamp.nanosec,header.frame_id,point,x,y,tx,ty,contour'
    )
    assert len(lines) == 1 + POINTS and lines[3] == '12,0,cam_front_optical,2,3.0,4.0,0.6,0.8,0'


def test_echo_timeout_and_bad_type_are_one_line_errors(ros_env):
    # distinct topics: the run given a type subscribes, which makes its topic appear in the graph
    cases = [
        (('/nothing', '--timeout', 1), 'did not appear within 1 s'),
        (
            ('/nothing', 'no_pkg/msg/Nope', '--timeout', 1),
            "unknown message type 'no_pkg/msg/Nope'",
        ),
        (('/silent', 'sensor_msgs/msg/Image', '--timeout', 1), 'no message on /silent'),
    ]
    processes = [(ros_env.start('echo', *args), message) for args, message in cases]
    for process, message in processes:
        _, stderr = process.communicate(timeout=30)
        assert process.returncode == 2 and 'Traceback' not in stderr
        assert stderr.count('\n') == 1 and message in stderr
