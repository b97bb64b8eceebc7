"""`memo-ros import videos` and `memo-ros export videos`.

Round trips through every calibration format, the demo.
"""

from pathlib import Path
import shutil

from conftest import memo_ros_cli as cli
import cv2
import numpy as np
import pytest

from memo_ros.core.formats.calibration import FORMATS, write_calibration
from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import load_default_body
from memo_ros.core.geometry.camera import Camera
from memo_ros.ros.bagio import (
    BagWriter,
    camera_info_msg,
    image_msg,
    read_messages,
    stamp_to_ns,
)
from memo_ros.tools.export_videos import export_videos
from memo_ros.tools.import_videos import (
    VideoImportError,
    fit_camera,
    import_videos,
    parse_frames,
    parse_offsets,
    recording_folder,
    scaled_camera,
)
from memo_ros.tools.simulate import START_NS, simulate

DEMO = Path(__file__).resolve().parent.parent.parent / 'shared' / 'data' / 'pose2sim_demo_single'
FRAMES, WIDTH, HEIGHT = 3, 160, 120
DISTORTION = [-0.18, 0.05, 0.0011, -0.0017, 0.01]
POINTS = np.random.default_rng(2).uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], (200, 3))


def images(bag: Path) -> dict[str, list[tuple[int, int, str, bytes]]]:
    """Per image topic: (log time, header stamp, encoding, pixel bytes) in order."""
    out = {}
    for m in read_messages(bag):
        if m.topic.endswith('/image_raw'):
            out.setdefault(m.topic, []).append(
                (
                    m.log_time_ns,
                    stamp_to_ns(m.message.header.stamp),
                    m.message.encoding,
                    bytes(m.message.data),
                )
            )
    return out


def max_reprojection(expected: list[Camera], got: list[Camera]) -> float:
    worst = 0.0
    for e, g in zip(expected, got, strict=True):
        uv_e, uv_g = e.project(POINTS), g.project(POINTS)
        front = np.all(np.isfinite(uv_e), axis=1)
        assert front.sum() > 50
        worst = max(worst, float(np.max(np.linalg.norm(uv_e[front] - uv_g[front], axis=1))))
    return worst


@pytest.fixture(scope='module')
def simulated(tmp_path_factory):
    """Return a small studio-arm bag.

    Its studio's cameras carry lens distortion and an off-centre principal point.
    """
    base = tmp_path_factory.mktemp('sim')
    result = simulate(
        'studio-arm', base / 'bag', frames=FRAMES, width=WIDTH, height=HEIGHT, empty_frames=1
    )
    studio = Studio.load(result.studio)
    for i, cam in enumerate(studio.cameras):
        cam.K[0, 2] += 1.3 * (i + 1)
        cam.K[1, 2] -= 0.7 * i
        cam.K[1, 1] *= 1.01
        cam.distortion_model, cam.D = 'plumb_bob', np.array(DISTORTION) * (1 + 0.2 * i)
    studio.save(result.studio)
    return result.bag, studio


@pytest.mark.parametrize('fmt', FORMATS)
def test_export_then_import_round_trip(simulated, tmp_path, fmt):
    bag, studio = simulated
    exported = export_videos(bag, tmp_path / 'videos', fmt=fmt)
    assert list(exported.videos) == studio.camera_names and not exported.notes
    assert set(exported.frames.values()) == {FRAMES + 1} and set(exported.offsets.values()) == {
        0.0
    }
    calibration = (
        exported.calibration[0] if len(exported.calibration) == 1 else tmp_path / 'videos'
    )
    result = import_videos(list(exported.videos.values()), calibration, tmp_path / 'back')
    assert [c.name for c in result.cameras] == studio.camera_names
    assert [(c.width, c.height) for c in result.cameras] == [(WIDTH, HEIGHT)] * 3
    assert max_reprojection(studio.cameras, result.cameras) < 0.1
    assert max_reprojection(studio.cameras, Studio.load(result.studio).cameras) < 0.1
    assert Studio.load(result.studio).frame_rate == studio.frame_rate
    assert images(result.bag) == images(
        bag
    )  # lossless codec: same pixels, same stamps, same order


def test_cli_round_trip_and_scaled_import(simulated, tmp_path):
    bag, studio = simulated
    done = cli(
        'export',
        'videos',
        bag,
        '--out',
        tmp_path / 'v',
        '--calibration-format',
        'toml',
        '--codec',
        'png',
    )
    assert done.returncode == 0, done.stderr
    assert 'import with  memo-ros import videos' in done.stdout
    videos = sorted((tmp_path / 'v').glob('*.avi'))
    done = cli(
        'import',
        'videos',
        *videos,
        '--calibration',
        tmp_path / 'v' / 'calibration.toml',
        '--out',
        tmp_path / 'half',
        '--scale',
        '0.5',
        '--encoding',
        'bgr8',
        '--frames',
        '1:3',
    )
    assert done.returncode == 0, done.stderr
    back = Studio.load(tmp_path / 'half.yaml')
    assert max_reprojection([c.scaled(0.5) for c in studio.cameras], back.cameras) < 0.1
    original, scaled = images(bag), images(tmp_path / 'half')
    for cam in studio.cameras:
        topic = f'/{cam.name}/image_raw'
        assert [s[1] for s in scaled[topic]] == [
            s[1] for s in original[topic][1:3]
        ]  # stamps of frames 1, 2
        for (_, _, _, grey), (_, _, encoding, bgr) in zip(original[topic][1:3], scaled[topic]):
            assert encoding == 'bgr8'
            full = np.frombuffer(grey, np.uint8).reshape(HEIGHT, WIDTH)
            expected = cv2.resize(
                np.repeat(full[..., None], 3, 2),
                (WIDTH // 2, HEIGHT // 2),
                interpolation=cv2.INTER_AREA,
            )
            assert np.array_equal(np.frombuffer(bgr, np.uint8).reshape(expected.shape), expected)
    stepped = import_videos(
        videos, tmp_path / 'v' / 'calibration.toml', tmp_path / 'stepped', frames=(0, None, 2)
    )
    assert stepped.frames == {c.name: 2 for c in studio.cameras}
    assert Studio.load(stepped.studio).frame_rate == pytest.approx(studio.frame_rate / 2)
    for cam in studio.cameras:  # frames 0 and 2, at their own stamps
        topic = f'/{cam.name}/image_raw'
        assert [s[1] for s in images(tmp_path / 'stepped')[topic]] == [
            s[1] for s in original[topic][0:3:2]
        ]


def test_names_order_rename_and_offsets(simulated, tmp_path):
    bag, studio = simulated
    exported = export_videos(bag, tmp_path / 'v', fmt='ros')
    renamed = []
    for i, name in enumerate(['front', 'side', 'top']):  # stems that name no calibration camera
        renamed.append(tmp_path / f'{name}.mkv')
        shutil.copy(exported.videos[studio.camera_names[i]], renamed[-1])
    by_order = import_videos(renamed, tmp_path / 'v', tmp_path / 'order')
    assert [c.name for c in by_order.cameras] == studio.camera_names
    reordered = import_videos(
        renamed[::-1],
        tmp_path / 'v',
        tmp_path / 'names',
        names=studio.camera_names[::-1],
        rename=True,
        offsets={'side': 0.01},
    )
    assert [c.name for c in reordered.cameras] == ['top', 'side', 'front']
    assert max_reprojection(studio.cameras[::-1], reordered.cameras) < 0.1
    got = images(tmp_path / 'names')
    original = images(bag)
    assert [s[3] for s in got['/side/image_raw']] == [
        s[3] for s in original['/cam_side/image_raw']
    ]
    assert [s[1] for s in got['/side/image_raw']] == [
        s[1] + 10_000_000 for s in original['/cam_side/image_raw']
    ]
    log_times = [m.log_time_ns for m in read_messages(tmp_path / 'names')]
    assert log_times == sorted(log_times)


def test_export_fills_gaps_and_reports_late_cameras(tmp_path):
    cam = Camera.look_at('cam_a', (3.0, 0.0, 1.0), (0.0, 0.0, 1.0), width=32, height=24, fx=40.0)
    cam_b = Camera.look_at('cam_b', (0.0, 3.0, 1.0), (0.0, 0.0, 1.0), width=32, height=24, fx=40.0)
    Studio('gap', [cam, cam_b], load_default_body(), frame_rate=10.0).save(tmp_path / 'bag.yaml')
    frames = [np.full((24, 32), 10 * k, np.uint8) for k in range(5)]
    with BagWriter(tmp_path / 'bag') as writer:
        for k in (0, 1, 3, 4):  # cam_a misses frame 2
            stamp = START_NS + k * 100_000_000
            writer.write(
                '/cam_a/camera_info', stamp, camera_info_msg(stamp, cam.to_camera_info_fields())
            )
            writer.write(
                '/cam_a/image_raw',
                stamp,
                image_msg(stamp, 'cam_a_optical_frame', frames[k], 'mono8'),
            )
        for k in (2, 3):  # cam_b starts 0.2 s late
            stamp = START_NS + k * 100_000_000
            writer.write(
                '/cam_b/image_raw',
                stamp,
                image_msg(stamp, 'cam_b_optical_frame', frames[k], 'mono8'),
            )
    result = export_videos(tmp_path / 'bag', tmp_path / 'v')
    assert result.frames == {'cam_a': 5, 'cam_b': 2} and result.offsets == {
        'cam_a': 0.0,
        'cam_b': 0.2,
    }
    assert any('cam_a: 1 missing frames filled' in n for n in result.notes)
    capture = cv2.VideoCapture(str(result.videos['cam_a']))
    levels = []
    while (frame := capture.read()[1]) is not None:
        levels.append(int(frame[0, 0, 0]))
    assert levels == [0, 10, 10, 30, 40]
    back = import_videos(
        list(result.videos.values()),
        result.calibration[0],
        tmp_path / 'back',
        offsets=result.offsets,
    )
    stamps = {t: [s[1] for s in v] for t, v in images(back.bag).items()}
    assert stamps['/cam_b/image_raw'] == [START_NS + k * 100_000_000 for k in (2, 3)]


def test_frame_size_must_match_the_calibration(simulated, tmp_path):
    bag, studio = simulated
    exported = export_videos(bag, tmp_path / 'v', fmt='toml')
    bigger = [
        Camera(
            c.name,
            c.width + 8,
            c.height,
            c.K,
            c.D,
            c.distortion_model,
            c.R_world_cam,
            c.t_world_cam,
        )
        for c in studio.cameras
    ]
    write_calibration(bigger, tmp_path / 'wide.toml', 'toml')
    videos = list(exported.videos.values())
    cropped = import_videos(
        videos, tmp_path / 'wide.toml', tmp_path / 'cropped'
    )  # within the codec crop
    assert [c.width for c in cropped.cameras] == [WIDTH] * 3 and len(cropped.notes) == 3
    assert max_reprojection(studio.cameras, cropped.cameras) < 0.1
    with pytest.raises(VideoImportError, match='calibrated for 168x120'):
        import_videos(videos, tmp_path / 'wide.toml', tmp_path / 'strict', crop_tolerance=0)
    smaller = [c.scaled(0.5) for c in studio.cameras]
    write_calibration(smaller, tmp_path / 'small.toml', 'toml')
    with pytest.raises(
        VideoImportError, match='is 160x120 but camera cam_front is calibrated for 80x60'
    ):
        import_videos(videos, tmp_path / 'small.toml', tmp_path / 'small')


def test_scaled_camera_follows_cv2_resize_for_rounded_sizes():
    cam = Camera(
        'c', 160, 120, [[150.0, 0.3, 81.2], [0.0, 151.0, 58.9], [0.0, 0.0, 1.0]], DISTORTION
    )
    assert scaled_camera(cam, 0.5) == cam.scaled(0.5)
    small = scaled_camera(cam, 0.33)  # 52.8 x 39.6 round to 53 x 40
    sx, sy = 53 / 160, 40 / 120
    uv = cam.project(POINTS + [0.0, 0.0, 3.0])
    expected = np.stack([(uv[:, 0] + 0.5) * sx - 0.5, (uv[:, 1] + 0.5) * sy - 0.5], -1)
    assert (small.width, small.height) == (53, 40)
    np.testing.assert_allclose(small.project(POINTS + [0.0, 0.0, 3.0]), expected, atol=1e-9)


def test_fit_camera_without_known_size_takes_the_video_size():
    cam = Camera('c', 1281, 721, [[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]])
    fitted, note = fit_camera(
        cam, 1280, 720, size_known=False, crop_tolerance=0, video=Path('c.mp4')
    )
    assert (fitted.width, fitted.height, note) == (1280, 720, None) and np.array_equal(
        fitted.K, cam.K
    )


def test_option_parsing():
    assert (
        parse_frames('2:7') == (2, 7, 1)
        and parse_frames(':5') == (0, 5, 1)
        and parse_frames('3:') == (3, None, 1)
        and parse_frames('0:100:2') == (0, 100, 2)
        and parse_frames('1::3') == (1, None, 3)
    )
    assert parse_offsets(['cam01=0.5', 'cam02=-0.016']) == {'cam01': 0.5, 'cam02': -0.016}
    for bad in ('5', '5:2', 'a:b', '-1:3', '0:4:0', '0:4:x', '0:4:2:1'):
        with pytest.raises(VideoImportError):
            parse_frames(bad)
    with pytest.raises(VideoImportError):
        parse_offsets(['cam01:0.5'])


def test_a_recording_folder_flat_or_as_a_pose2sim_project(simulated, tmp_path):
    """``import videos FOLDER``: its videos in natural order and its one calibration."""
    bag, studio = simulated
    exported = export_videos(bag, tmp_path / 'v', fmt='toml', codec='png')
    project = tmp_path / 'project'
    (project / 'videos').mkdir(parents=True)
    (project / 'calibration').mkdir()
    for video in exported.videos.values():
        shutil.copy(video, project / 'videos' / video.name)
    shutil.copy(exported.calibration[0], project / 'calibration' / 'Calib_scene.toml')
    done = cli('import', 'videos', project, '--out', tmp_path / 'p', '--frames', '0:2')
    assert done.returncode == 0, done.stderr
    assert Studio.load(tmp_path / 'p.yaml').camera_names == studio.camera_names
    assert images(tmp_path / 'p') == {
        topic: frames[:2] for topic, frames in images(bag).items() if 'image' in topic
    }
    flat = tmp_path / 'flat'
    flat.mkdir()
    for path in (*exported.videos.values(), exported.calibration[0]):
        shutil.copy(path, flat / path.name.replace('calibration', 'Calib'))
    assert recording_folder(flat) == (
        sorted((flat / v.name for v in exported.videos.values()), key=lambda p: p.name),
        flat / 'Calib.toml',
    )
    (flat / 'Calib_other.toml').write_text('')
    cases = [
        ([flat], '2 calibrations (Calib*.toml or *.qca.txt'),
        ([tmp_path / 'project' / 'calibration'], '0 videos'),
    ]
    for args, message in cases:
        done = cli('import', 'videos', *args, '--out', tmp_path / 'out')
        assert done.returncode == 2, (message, done.stderr)
        assert message in done.stderr and 'Traceback' not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    done = cli('import', 'videos', flat, '-c', flat / 'Calib.toml', '--out', tmp_path / 'chosen')
    assert done.returncode == 0, done.stderr
    done = cli('import', 'videos', *exported.videos.values(), '--out', tmp_path / 'out')
    assert done.returncode == 2 and '--calibration is needed' in done.stderr, done.stderr


def test_bad_inputs_are_one_line_errors(simulated, tmp_path):
    bag, studio = simulated
    exported = export_videos(bag, tmp_path / 'v', fmt='qualisys')
    videos = list(exported.videos.values())
    calibration = exported.calibration[0]
    (tmp_path / 'broken.mp4').write_text('not a video')
    (tmp_path / 'notes.txt').write_text('not a calibration')
    renamed = tmp_path / 'other.mkv'
    shutil.copy(videos[0], renamed)
    cases = [
        (videos[:2] + [tmp_path / 'x.mkv'], calibration, [], 'no video at'),
        ([tmp_path / 'broken.mp4'] + videos[1:], calibration, [], 'cannot read video'),
        (videos, tmp_path / 'notes.txt', [], 'unknown calibration format'),
        ([renamed], calibration, [], '1 videos but 3 calibrated cameras'),
        (videos, calibration, ['--frames', '10:20'], 'no frames in range 10:20'),
        (videos, calibration, ['--offset', 'cam_x=1'], 'unknown camera cam_x'),
        (videos, calibration, ['--names', 'cam_top,cam_top,cam_side'], 'more than one video'),
    ]
    for vids, calib, extra, message in cases:
        done = cli(
            'import', 'videos', *vids, '--calibration', calib, '--out', tmp_path / 'out', *extra
        )
        assert done.returncode == 2, (message, done.stderr)
        assert message in done.stderr and 'Traceback' not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    done = cli('export', 'videos', tmp_path / 'nothing', '--out', tmp_path / 'e')
    assert (
        done.returncode == 2 and 'no studio file' in done.stderr and 'Traceback' not in done.stderr
    )


@pytest.mark.skipif(
    not (DEMO / 'Calib.qca.txt').is_file(), reason='Pose2Sim demo data not available'
)
def test_pose2sim_demo_imports(tmp_path):
    videos = [DEMO / f'cam0{i}.mp4' for i in range(1, 5)]
    done = cli(
        'import',
        'videos',
        *videos,
        '--calibration',
        DEMO / 'Calib.qca.txt',
        '--out',
        tmp_path / 'p2s',
        '--scale',
        '0.25',
        '--frames',
        '0:5',
    )
    assert done.returncode == 0, done.stderr
    folder = cli(
        'import', 'videos', DEMO, '--out', tmp_path / 'f', '--scale', '0.25', '--frames', '0:1'
    )
    assert folder.returncode == 0 and 'Calib.qca.txt' not in folder.stderr, folder.stderr
    assert Studio.load(tmp_path / 'f.yaml').camera_names == ['cam01', 'cam02', 'cam03', 'cam04']
    # cam01 and cam02 are encoded 1080 wide, cam03 and cam04 1088 like the calibration's fov_video
    assert done.stderr.count('cropped at the right') == 2
    studio = Studio.load(tmp_path / 'p2s.yaml')
    assert (
        studio.camera_names == ['cam01', 'cam02', 'cam03', 'cam04'] and studio.frame_rate == 60.0
    )
    assert [(c.width, c.height) for c in studio.cameras] == [
        (270, 480),
        (270, 480),
        (272, 480),
        (272, 480),
    ]
    got = images(tmp_path / 'p2s')
    for cam in studio.cameras:
        frames = got[f'/{cam.name}/image_raw']
        assert len(frames) == 5
        assert all(len(data) == cam.width * cam.height for _, _, _, data in frames)
        assert [f[1] for f in frames] == [START_NS + round(k / 60 * 1e9) for k in range(5)]
        origin = cam.project(np.zeros(3))
        assert 0 <= origin[0] < cam.width and 0 <= origin[1] < cam.height
