"""The simulator's bags.

Topics, counts, stamps, calibration, truth kinematics, encodings, seeds, the person.
"""

from collections import defaultdict
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import load_studio_actor
from memo_ros.core.geometry.render import SHAPES, render
from memo_ros.core.geometry.rotations import quat_to_matrix
from memo_ros.core.simulation.imaging import (
    PART_TINT,
    ImagingOptions,
    background_image,
    compose_frame,
)
from memo_ros.core.simulation.scenarios import (
    SCENARIOS,
    STUDIO_EMPTY_FRAMES,
    make_scenario,
)
from memo_ros.ros.bagio import bag_topics, read_messages, stamp_to_ns
from memo_ros.ros.bagio import grey_images as bag_grey_images
from memo_ros.tools.simulate import (
    ENCODINGS,
    START_NS,
    TRUTH_JOINTS,
    TRUTH_POSES,
    simulate,
)

ROOT = Path(__file__).resolve().parent.parent
# what the `memo-ros` entry point runs (`-m memo_ros.tools.cli` loads cli.py twice, splitting
# CliError)
CLI_ENTRY = 'import sys; from memo_ros.tools.cli import main; sys.exit(main())'
FRAMES = 4
WIDTH, HEIGHT = 160, 120
NOISE_FREE = ImagingOptions(noise=0.0, blur=0.0, lighting_change=0.0, seed=0)
WALKING = ('studio-walk', 'street-walk')


def grey_images(bag: Path, topic: str) -> list[np.ndarray]:
    """Every image of ``topic`` decoded to grey levels like the contour node does."""
    return [grey for _, grey in bag_grey_images(bag, topic)]


def raw_images(bag: Path, topic: str) -> list[bytes]:
    """Return the undecoded pixel bytes of every image of ``topic``."""
    return [bytes(m.message.data) for m in read_messages(bag, [topic])]


def truth_q(message, body) -> np.ndarray:
    """Generalized coordinates in the body's order from a truth JointState."""
    values = dict(zip(message.name, message.position))
    return np.array([values[n] for n in body.coordinate_names])


@pytest.fixture(scope='module', params=SCENARIOS)
def simulated(request, tmp_path_factory):
    """Each scenario simulated small, with its messages grouped by topic."""
    result = simulate(
        request.param,
        tmp_path_factory.mktemp(request.param) / 'bag',
        frames=FRAMES,
        width=WIDTH,
        height=HEIGHT,
    )
    by_topic = defaultdict(list)
    for m in read_messages(result.bag):
        by_topic[m.topic].append(m)
    return request.param, result, by_topic


def test_topics_types_and_counts(simulated):
    name, result, by_topic = simulated
    cameras = make_scenario(name, load_studio_actor()).cameras
    assert result.cameras == [c.name for c in cameras] and result.frames == FRAMES
    expected = {
        TRUTH_JOINTS: 'sensor_msgs/msg/JointState',
        TRUTH_POSES: 'geometry_msgs/msg/PoseArray',
    }
    for cam in result.cameras:
        expected[f'/{cam}/image_raw'] = 'sensor_msgs/msg/Image'
        expected[f'/{cam}/camera_info'] = 'sensor_msgs/msg/CameraInfo'
    assert bag_topics(result.bag) == expected
    # the cameras also see the empty scene first; the truth exists only while the subject is there
    counts = {
        topic: FRAMES + (0 if topic.startswith('/memo/truth') else result.empty_frames)
        for topic in expected
    }
    assert {topic: len(ms) for topic, ms in by_topic.items()} == counts
    assert result.empty_frames == (0 if name == 'street-walk' else STUDIO_EMPTY_FRAMES)


def test_stamps_increase_at_the_frame_rate(simulated):
    _, result, by_topic = simulated
    rate = Studio.load(result.studio).frame_rate
    for topic, messages in by_topic.items():
        stamps = np.array([stamp_to_ns(m.message.header.stamp) for m in messages], np.int64)
        first = START_NS + (
            round(result.empty_frames * 1e9 / rate) if topic.startswith('/memo/truth') else 0
        )
        assert stamps[0] == first, topic
        assert np.all(np.abs(np.diff(stamps) - 1e9 / rate) <= 1.0), topic
        assert np.array_equal(stamps, [m.log_time_ns for m in messages]), topic


def test_empty_studio_frames_show_the_background_and_configure_the_contour_node(tmp_path):
    result = simulate(
        'studio-arm',
        tmp_path / 'bag',
        frames=2,
        width=WIDTH,
        height=HEIGHT,
        options=NOISE_FREE,
        empty_frames=3,
    )
    studio = Studio.load(result.studio)
    params = studio.node_parameters['contour_node']
    assert params['segmenter'] == 'background' and params['background_frames'] == 3
    cam = studio.cameras[0]
    images = grey_images(result.bag, f'/{cam.name}/image_raw')
    empty = np.clip(background_image(cam, 0) + 0.5, 0, 255).astype(np.uint8)
    assert all(np.array_equal(image, empty) for image in images[:3])
    assert not np.array_equal(images[3], empty)


def test_camera_info_matches_the_studio_file(simulated):
    _, result, by_topic = simulated
    studio = Studio.load(result.studio)
    assert studio.camera_names == result.cameras
    for cam in studio.cameras:
        assert (cam.width, cam.height) == (WIDTH, HEIGHT)
        for m in by_topic[f'/{cam.name}/camera_info']:
            info = m.message
            assert (info.width, info.height) == (cam.width, cam.height)
            assert info.header.frame_id == f'{cam.name}_optical_frame'
            assert np.allclose(np.reshape(info.k, (3, 3)), cam.K, rtol=0, atol=1e-12)
            assert np.allclose(
                info.d, np.pad(cam.D, (0, len(info.d) - len(cam.D))), rtol=0, atol=1e-12
            )
        for m in by_topic[f'/{cam.name}/image_raw']:
            assert (m.message.width, m.message.height) == (cam.width, cam.height)
            assert m.message.header.frame_id == f'{cam.name}_optical_frame'


def test_truth_poses_are_the_forward_kinematics_of_the_truth_joints(simulated):
    name, _, by_topic = simulated
    body = load_studio_actor()
    expected_names = list(body.coordinate_names) + (['gait_phase'] if name in WALKING else [])
    for joints, poses in zip(by_topic[TRUTH_JOINTS], by_topic[TRUTH_POSES]):
        assert list(joints.message.name) == expected_names
        assert len(joints.message.velocity) == len(expected_names)
        assert joints.message.header.stamp == poses.message.header.stamp
        rotations, origins = body.forward_kinematics(truth_q(joints.message, body))
        p = poses.message.poses
        assert np.allclose(
            [[x.position.x, x.position.y, x.position.z] for x in p], origins, rtol=0, atol=1e-9
        )
        quats = np.array(
            [[x.orientation.x, x.orientation.y, x.orientation.z, x.orientation.w] for x in p]
        )
        assert np.allclose(quat_to_matrix(quats), rotations, rtol=0, atol=1e-9)


def test_every_encoding_decodes_to_the_mono8_grey_image(tmp_path):
    # colour frames tint clothing with unit-luma tints (imaging.PART_TINT), so every layout
    # converts back to the mono8 picture up to rounding
    topic = '/cam_front/image_raw'
    greys = {}
    for encoding in ENCODINGS:
        result = simulate(
            'studio-arm',
            tmp_path / encoding,
            frames=2,
            width=WIDTH,
            height=HEIGHT,
            options=NOISE_FREE,
            encoding=encoding,
        )
        greys[encoding] = np.stack(grey_images(result.bag, topic)).astype(int)
    assert np.array_equal(greys['mono16'], greys['mono8'])
    for encoding in ('rgb8', 'bgr8', 'rgba8', 'bgra8'):
        assert np.array_equal(greys[encoding], greys['rgb8']), encoding
        assert np.abs(greys[encoding] - greys['mono8']).max() <= 2, encoding
    assert any(PART_TINT)


def test_same_seed_gives_identical_bytes_and_the_seed_drives_the_background(tmp_path):
    runs = {}
    for label, seed in (('a', 7), ('b', 7), ('c', 8)):
        options = ImagingOptions(noise=3.0, seed=seed)
        result = simulate(
            'street-walk', tmp_path / label, frames=3, width=WIDTH, height=HEIGHT, options=options
        )
        runs[label] = raw_images(result.bag, '/cam_street/image_raw')
    assert runs['a'] == runs['b']
    assert all(x != y for x, y in zip(runs['a'], runs['c']))
    quiet = [
        simulate(
            'street-walk',
            tmp_path / f'quiet{seed}',
            frames=1,
            width=WIDTH,
            height=HEIGHT,
            options=ImagingOptions(noise=0.0, seed=seed),
        )
        for seed in (1, 2)
    ]
    first, second = (raw_images(r.bag, '/cam_street/image_raw')[0] for r in quiet)
    assert first != second  # no noise, but the background texture comes from the seed


@pytest.mark.parametrize('shape', SHAPES)
def test_the_person_is_in_the_image_exactly_where_the_body_renders(tmp_path, shape):
    result = simulate(
        'studio-arm',
        tmp_path / 'bag',
        frames=3,
        width=WIDTH,
        height=HEIGHT,
        options=NOISE_FREE,
        shape=shape,
    )
    body = load_studio_actor()
    scenario = make_scenario('studio-arm', body, WIDTH, HEIGHT, 3)
    joints = [m.message for m in read_messages(result.bag, [TRUTH_JOINTS])]
    rng = np.random.default_rng(0)
    for cam in scenario.cameras:
        background = background_image(cam, NOISE_FREE.seed)
        images = grey_images(result.bag, f'/{cam.name}/image_raw')[result.empty_frames :]
        for k, (image, message) in enumerate(zip(images, joints)):
            rotations, origins = body.forward_kinematics(truth_q(message, body))
            rendering = render(
                cam, rotations, origins, body.semi_axes, body.lengths, normals=True, shape=shape
            )
            nobody = render(
                cam,
                rotations,
                origins,
                body.semi_axes,
                body.lengths,
                parts=np.array([], int),
                normals=True,
            )
            empty = compose_frame(background, nobody, cam, NOISE_FREE, k, rng)
            changed = image != empty
            person = rendering.label > 0
            assert person.sum() > 50, cam.name
            assert not np.any(changed & ~person), cam.name
            assert changed[person].mean() > 0.9, (
                cam.name
            )  # a shaded pixel may equal the background by chance


def test_bad_scenario_name_is_one_line_and_exit_2(tmp_path):
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get('PYTHONPATH')])),
    )
    done = subprocess.run(
        [sys.executable, '-c', CLI_ENTRY, 'simulate', 'moon-walk', '--out', str(tmp_path / 'bag')],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert 'Traceback' not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and 'moon-walk' in lines[0] and 'studio-arm' in lines[0]
    assert not (tmp_path / 'bag').exists()
