"""studio-dance and the ring4 rig: a smooth, valid, fully turning dance every camera sees.

Also `memo-ros simulate`'s --heading and --rig (no DDS).
"""

from __future__ import annotations

from conftest import memo_ros_cli
import numpy as np
import pytest

from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import PART_NAMES, load_studio_actor, lowest_point
from memo_ros.core.multiview.anatomy import facing, pose_problem
from memo_ros.core.simulation.scenarios import (
    RIGS,
    make_scenario,
    ring4_cameras,
    studio_cameras,
)
from memo_ros.tools.simulate import simulate

BODY = load_studio_actor()
DT = 1.0 / 30.0


def _dance(heading_deg: float = 0.0, rig: str = 'orthogonal', frames: int | None = None):
    """Return the studio-dance scenario and its coordinates at its frames (N, n)."""
    scenario = make_scenario(
        'studio-dance', BODY, frames=frames, heading=np.radians(heading_deg), rig=rig
    )
    q, phase = scenario.coordinates(np.arange(scenario.frames) / scenario.frame_rate)
    assert phase is None
    return scenario, q


def test_every_frame_is_a_pose_a_person_can_take_with_the_feet_on_the_floor():
    scenario, q = _dance(heading_deg=170.0)
    assert scenario.frames == 120 and scenario.frame_rate == 30.0
    problems = [(k, pose_problem(BODY, x, None)) for k, x in enumerate(q)]
    assert [p for p in problems if p[1]] == []
    rotations, origins = BODY.forward_kinematics(q)
    lowest = np.array([lowest_point(BODY, r, o) for r, o in zip(rotations, origins)])
    assert lowest.min() > -1e-9 and lowest.max() < 0.01  # one foot always on the floor
    assert np.all(np.abs(q[:, 5]) <= np.pi) and np.all(q[:, 3:5] == 0.0)  # a wrapped yaw


def test_the_motion_is_smooth_and_its_velocities_are_its_derivative():
    scenario, _ = _dance(heading_deg=120.0)  # the yaw wraps at pi during the turn
    fine = np.arange(0.0, 4.0, 1e-3)
    q, _ = scenario.coordinates(fine)
    step = np.diff(q, axis=0)
    step[:, 3:] = np.angle(np.exp(1j * step[:, 3:]))  # the wrapped yaw is the same rotation
    assert np.abs(step).max() < 0.01  # no jump: < 10 rad/s anywhere
    velocity = scenario.velocities(fine)
    assert np.allclose(step / 1e-3, 0.5 * (velocity[1:] + velocity[:-1]), atol=1e-3)
    acceleration = np.diff(velocity, axis=0) / 1e-3
    # C1: the velocities have no jump either (a jump of 0.15 rad/s would read 150 here)
    assert np.abs(acceleration).max() < 150.0
    assert np.abs(velocity[:, 5]).max() == pytest.approx(2 * np.pi * np.pi / 2 / 1.2, rel=1e-3)


def test_the_dance_has_its_moves_a_full_turn_and_starts_at_the_heading():
    for heading in (0.0, 45.0, 225.0, -90.0):
        _, q = _dance(heading_deg=heading)
        yaw = np.unwrap(facing(BODY, q))
        start = np.degrees(np.angle(np.exp(1j * (yaw[0] - np.radians(heading)))))
        assert start == pytest.approx(0.0, abs=1e-9), heading
        assert np.degrees(yaw[-1] - yaw[0]) == pytest.approx(360.0, abs=1e-6)
        turning = np.flatnonzero(np.abs(np.diff(yaw)) > 1e-9) * DT
        assert turning.max() - turning.min() == pytest.approx(1.2, abs=2 * DT)
    _, q = _dance()
    idx = BODY.coordinate_index
    for side in 'lr':
        assert q[:, idx(f'shoulder_{side}_y')].max() > 2.5  # overhead
        assert q[:, idx(f'hip_{side}_y')].max() == pytest.approx(1.3, abs=0.01)  # the kick
        kick = q[:, idx(f'hip_{side}_y')]
        rise = np.flatnonzero(kick > 0.01)[0], int(np.argmax(kick))
        assert (rise[1] - rise[0]) * DT <= 0.45
        assert q[:, idx(f'knee_{side}_y')].min() < -0.9  # the knee bends
    raised = [np.flatnonzero(q[:, idx(f'shoulder_{s}_y')] > 2.0) for s in 'lr']
    assert raised[0].max() < raised[1].max() and raised[0].min() < raised[1].min()
    assert q[0, 2] - q[:, 2].min() == pytest.approx(0.1, abs=0.005)  # the squat
    assert 0.1 < np.hypot(q[-1, 0] - q[0, 0], q[-1, 1] - q[0, 1]) < 0.3  # a small step


def test_every_ring4_camera_sees_the_whole_body_in_every_frame():
    scenario, q = _dance(heading_deg=30.0, rig='ring4')
    assert [c.name for c in scenario.cameras] == [c.name for c in ring4_cameras()]
    _, origins = BODY.forward_kinematics(q)
    for camera in scenario.cameras:
        uv = camera.project(origins.reshape(-1, 3))
        inside = (
            (uv[:, 0] > 0)
            & (uv[:, 0] < camera.width - 1)
            & (uv[:, 1] > 0)
            & (uv[:, 1] < camera.height - 1)
        )
        assert inside.all(), camera.name
    centres = np.array([c.centre for c in scenario.cameras])
    axes = (np.array([0.0, 0.0, 1.0]) - centres) / np.linalg.norm(
        np.array([0.0, 0.0, 1.0]) - centres, axis=1, keepdims=True
    )
    angles = np.degrees(np.arccos(np.clip(axes @ axes.T, -1, 1)))[np.triu_indices(4, 1)]
    assert np.all(np.abs(angles - 90.0) > 1.0) and np.all(angles < 170.0)  # not orthogonal


def test_rig_and_heading_options_are_checked():
    assert RIGS == ('orthogonal', 'ring4')
    arm = make_scenario('studio-arm', BODY, rig='ring4')
    assert len(arm.cameras) == 4 and 'four cameras' in arm.description
    walk = make_scenario('studio-walk', BODY)
    assert [c.name for c in walk.cameras] == [c.name for c in studio_cameras()]
    for name, options, words in (
        ('studio-arm', {'heading': 1.0}, 'takes no heading'),
        ('street-walk', {'rig': 'ring4'}, 'its own camera'),
        ('studio-dance', {'rig': 'ring5'}, 'unknown rig'),
        ('studio-dance', {'heading': float('nan')}, 'finite'),
    ):
        with pytest.raises(ValueError, match=words):
            make_scenario(name, BODY, **options)


def test_simulate_writes_the_rig_and_the_first_pose_into_the_studio(tmp_path):
    result = simulate(
        'studio-dance',
        tmp_path / 'bag',
        frames=2,
        width=160,
        height=120,
        heading=np.radians(200.0),
        rig='ring4',
        empty_frames=0,
    )
    studio = Studio.load(result.studio)
    assert studio.camera_names == [c.name for c in ring4_cameras()] == result.cameras
    for camera, expected in zip(studio.cameras, ring4_cameras(160, 120)):
        assert np.allclose(camera.centre, expected.centre) and np.allclose(camera.K, expected.K)
    first = np.array([studio.initial_pose[n] for n in BODY.coordinate_names])
    assert np.degrees(facing(BODY, first)) == pytest.approx(200.0 - 360.0)
    assert len(PART_NAMES) == 14


def test_simulate_cli_heading_default_is_random_from_the_seed_and_printed(tmp_path):
    outputs = []
    for label, seed in (('a', 3), ('b', 3), ('c', 4)):
        done = memo_ros_cli(
            'simulate', 'studio-dance', '--frames', 1, '--width', 80, '--height', 60,
            '--empty-frames', 0, '--seed', seed, '--out', tmp_path / label,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        line = next(x for x in done.stdout.splitlines() if x.startswith('heading'))
        assert f'random from --seed {seed}' in line
        heading = float(line.split()[1])
        pose = Studio.load(tmp_path / f'{label}.yaml').initial_pose
        first = np.array([pose[n] for n in BODY.coordinate_names])
        assert np.degrees(np.angle(np.exp(1j * (facing(BODY, first) - np.radians(heading))))) == (
            pytest.approx(0.0, abs=0.06)
        )
        outputs.append(heading)
    assert outputs[0] == outputs[1] != outputs[2]
    done = memo_ros_cli(
        'simulate', 'studio-dance', '--heading', -45, '--rig', 'ring4', '--frames', 1,
        '--width', 80, '--height', 60, '--empty-frames', 0, '--out', tmp_path / 'given',
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert 'heading    -45.0 deg (given)' in done.stdout and 'rig        ring4' in done.stdout


@pytest.mark.parametrize(
    ('args', 'words'),
    [
        (('studio-dance', '--heading', 'nan'), 'must be a finite number, not nan'),
        (('studio-dance', '--heading', 'east'), 'must be a finite number, not east'),
        (('studio-dance', '--rig', 'ring5'), "unknown rig 'ring5'; known: orthogonal, ring4"),
        (('street-walk', '--rig', 'ring4'), '--rig is for the studio scenarios'),
        (('studio-arm', '--heading', '30'), '--heading is for studio-dance'),
    ],
)
def test_simulate_cli_refuses_bad_heading_and_rig_in_one_line(tmp_path, args, words):
    done = memo_ros_cli('simulate', *args, '--frames', 1, '--out', tmp_path / 'bag')
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert words in lines[-1] and 'Traceback' not in done.stderr, done.stderr
    assert not (tmp_path / 'bag').exists()
