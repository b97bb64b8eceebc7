"""Active viewpoint selection (Kakadiaris & Metaxas §4) in the ROS-free core.

VI, observability, assignment.
"""

from __future__ import annotations

import numpy as np
import pytest

from memo_ros.core.geometry.body import PART_NAMES, load_studio_actor
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import render, render_labels
from memo_ros.core.multiview.selection import (
    MODE_ALL_CAMERAS,
    Assignment,
    CameraLiveness,
    CameraSelector,
    SelectionSettings,
    assignment,
    visibility_index,
)
from memo_ros.core.simulation.scenarios import make_scenario, studio_cameras

BODY = load_studio_actor()
CAMERAS = studio_cameras()
NAMES = [c.name for c in CAMERAS]


def part(name: str) -> int:
    return PART_NAMES.index(name)


PAPER_VI = 0.2  # Kakadiaris §4's visibility threshold (the default is 0)


def cam(name: str) -> int:
    return NAMES.index(name)


def test_part_hidden_behind_the_torso_has_vi_near_0_there_and_near_1_from_an_orthogonal_camera():
    q = BODY.neutral()  # right arm hanging a little away from the torso's right side
    q[BODY.coordinate_index('shoulder_r_x')] = -0.2  # cam_side looks from the body's left
    a = CameraSelector(BODY, CAMERAS, SelectionSettings(vi_threshold=PAPER_VI)).assign(q, q)
    arm = part('upper_arm_r')
    assert a.vi[arm, cam('cam_side')] < 0.05
    assert a.vi[arm, cam('cam_front')] > 0.95
    assert 'cam_side' not in a.cameras_for(arm) and a.cameras_for(arm)[0] in (
        'cam_front',
        'cam_top',
    )
    assert a.observed.all()  # every part is seen by some camera
    default = CameraSelector(BODY, CAMERAS).assign(q, q)  # vi_threshold 0: the arm is in its view
    assert default.cameras_for(arm)[-1] == 'cam_side' and len(default.cameras_for(arm)) == 3


def _vertical_cylinder_pose(y: float, x: float) -> tuple[np.ndarray, np.ndarray]:
    return np.eye(3), np.array([x, y, -0.3])  # part frame z up, centred on z = 0


def _image_interval(f: float, y: float, depth: float, r: float) -> tuple[float, float]:
    """Exact image-x interval of a vertical circular cylinder's silhouette.

    Tangent lines from the centre.
    """
    centre = np.arctan2(y, depth)
    half = np.arcsin(r / np.hypot(y, depth))
    return f * np.tan(centre - half), f * np.tan(centre + half)


@pytest.mark.parametrize('offset', [0.03, 0.08, 0.14])
@pytest.mark.parametrize('scale', [1.0, 0.5])
def test_vi_matches_the_analytic_area_ratio_of_two_overlapping_cylinders(offset, scale):
    r, length, distance, f = 0.1, 0.6, 20.0, 8000.0
    camera = Camera.look_at(
        'far', eye=(distance, 0.0, 0.0), target=(0.0, 0.0, 0.0), width=400, height=400, fx=f
    )
    poses = [
        _vertical_cylinder_pose(0.0, -0.3),
        _vertical_cylinder_pose(offset, 0.3),
    ]  # back, front
    rotations = np.stack([p[0] for p in poses])
    origins = np.stack([p[1] for p in poses])
    semi_axes = np.full((2, 2), r)
    lengths = np.full(2, length)
    vi = visibility_index(render(camera, rotations, origins, semi_axes, lengths, scale=scale), 2)
    # the front cylinder is taller in the image, so only the widths overlap: VI = 1 - overlap /
    # width
    back = _image_interval(f, 0.0, distance + 0.3, r)
    front = _image_interval(f, offset, distance - 0.3, r)
    overlap = max(0.0, min(back[1], front[1]) - max(back[0], front[0]))
    expected = 1.0 - overlap / (back[1] - back[0])
    assert vi[1] == pytest.approx(1.0)
    assert vi[0] == pytest.approx(expected, abs=0.02 if scale == 1.0 else 0.04)


@pytest.mark.parametrize('norm', ['norm_of_sum', 'sum_of_norms'])
@pytest.mark.parametrize('camera', NAMES)
def test_motion_along_a_cameras_optical_axis_ranks_that_camera_last(camera, norm):
    settings = SelectionSettings(
        vi_threshold=PAPER_VI, max_cameras_per_part=3, observability_norm=norm
    )
    q_prev = BODY.neutral()
    q_pred = q_prev.copy()
    q_pred[0:3] += 0.05 * CAMERAS[cam(camera)].R_world_cam[:, 2]  # 5 cm along the optical axis
    a = CameraSelector(BODY, CAMERAS, settings).assign(q_prev, q_pred)
    k = cam(camera)
    checked = 0
    for i in range(len(PART_NAMES)):
        chosen = a.cameras_for(i)
        if camera in chosen and len(chosen) > 1:
            assert chosen[-1] == camera, (PART_NAMES[i], chosen, a.observability[i])
            checked += 1
    assert checked >= 5
    # with two cameras per part, a camera the part moves straight towards is left out wherever
    # there is a choice
    two = CameraSelector(
        BODY,
        CAMERAS,
        SelectionSettings(vi_threshold=PAPER_VI, max_cameras_per_part=2, observability_norm=norm),
    ).assign(q_prev, q_pred)
    seen_by_three = (two.vi >= PAPER_VI).all(axis=1)
    assert seen_by_three.any() and not two.selected[seen_by_three, k].any()


def test_spin_about_the_parts_own_axis_cancels_in_the_papers_norm_of_sum_not_in_the_sum_of_norms():
    q_prev = BODY.neutral()
    q_prev[BODY.coordinate_index('shoulder_r_y')] = (
        np.pi / 2
    )  # right arm straight forward, horizontal
    q_pred = q_prev.copy()
    q_pred[BODY.coordinate_index('elbow_r_z')] += 0.1  # forearm (and hand) twist about its axis
    rotations, origins = BODY.forward_kinematics(q_prev)
    hand = part('hand_r')
    axis = rotations[hand][:, 2]
    tip = origins[hand] + axis * BODY.lengths[hand]
    end_on = Camera.look_at(
        'end_on', eye=tip + 2.0 * axis, target=tip, width=640, height=480, fx=650.0
    )
    figures = {}
    for norm in ('norm_of_sum', 'sum_of_norms'):
        selector = CameraSelector(
            BODY, [end_on, CAMERAS[cam('cam_side')]], SelectionSettings(observability_norm=norm)
        )
        figures[norm] = selector.assign(q_prev, q_pred).observability[:, 0]
    # the hand's rim turns about 1 px per node in the image (the forearm's shows only around the
    # hand) ...
    for name, least in (('hand_r', 20.0), ('forearm_r', 2.0)):
        i = part(name)
        assert figures['sum_of_norms'][i] > least
        assert (
            figures['norm_of_sum'][i] < 1e-6 * figures['sum_of_norms'][i]
        )  # ... and the motions sum to 0
    assert figures['norm_of_sum'][part('torso')] == pytest.approx(
        0.0, abs=1e-9
    )  # nothing else moved


def test_camera_timeout_drops_the_camera_and_restores_it_when_it_comes_back():
    ns = 1_000_000_000
    live = CameraLiveness(NAMES, timeout_s=0.3, contours_timeout_s=0.3)

    def alive(t: float) -> dict[str, bool]:  # judged at t, the cameras running in real time
        return live.alive(int(t * ns), wall=t)

    def seen(name: str, t: float, sources=CameraLiveness.SOURCES) -> None:
        for source in sources:
            live.seen(name, int(t * ns), source, wall=t)

    assert all(alive(0.0).values())  # never heard of yet: counted from the first frame
    for t in (0.0, 0.1):
        for name in NAMES:
            seen(name, t)
    for t in (0.2, 0.3, 0.4, 0.5):  # cam_top falls silent after 0.1 s
        for name in NAMES[:2]:
            seen(name, t)
    assert alive(0.4)['cam_top']  # 0.3 s silent: still within the timeout
    now = alive(0.5)
    assert not now['cam_top'] and now['cam_front'] and now['cam_side']
    selector = CameraSelector(BODY, CAMERAS)
    q = BODY.neutral()
    dropped = selector.assign(q, q, now)
    top = cam('cam_top')
    assert (
        not dropped.alive[top]
        and not dropped.selected[:, top].any()
        and np.isnan(dropped.vi[:, top]).all()
    )
    seen('cam_top', 0.6)  # its camera_info and contours arrive again
    now = alive(0.6)
    assert all(now.values())
    restored = selector.assign(q, q, now)
    assert restored.alive.all() and restored.selected[:, top].any()
    # the camera still sends camera_info but its contour_node is gone: not alive either
    for t in (0.7, 0.8, 0.9, 1.0):
        for name in NAMES:
            seen(name, t, ('camera_info',) if name == 'cam_side' else CameraLiveness.SOURCES)
    assert alive(0.8)['cam_side'] and not alive(0.9)['cam_side']  # its contours last came at 0.5 s
    # a contour_node lagging 0.5 s behind its camera still delivers: alive
    for t in (1.1, 1.2, 1.3):
        seen('cam_side', t, ('camera_info',))
        live.seen('cam_side', int((t - 0.5) * ns), 'contours', wall=t)
    assert alive(1.3)['cam_side']
    # a burst of camera_info ahead of the contours (fast replay) within the wall timeout: alive
    for k in range(20):
        live.seen('cam_side', int((1.4 + 0.05 * k) * ns), 'camera_info', wall=1.31)
    assert live.alive(int(2.35 * ns), wall=1.32)['cam_side']
    live.require_contours = False  # a selector without contour nodes: camera_info suffices
    assert live.alive(int(2.35 * ns), wall=5.0)['cam_side']
    # without any camera_info at all, a camera drops out once the timeout has passed since the
    # first frame
    fresh = CameraLiveness(NAMES, timeout_s=0.3)
    fresh.alive(0, wall=0.0)
    fresh.seen('cam_front', int(0.5 * ns), 'camera_info', wall=0.5)
    fresh.seen('cam_front', int(0.5 * ns), 'contours', wall=0.5)
    assert fresh.alive(int(0.5 * ns), wall=0.5) == {
        'cam_front': True,
        'cam_side': False,
        'cam_top': False,
    }


def test_a_part_no_live_camera_sees_is_unobserved_and_every_part_keeps_at_most_max_cameras():
    q = BODY.neutral()
    only_side = CameraSelector(BODY, CAMERAS, SelectionSettings(vi_threshold=PAPER_VI)).assign(
        q, q, {'cam_front': False, 'cam_top': False}
    )
    arm = part('upper_arm_r')
    assert not only_side.observed[arm] and only_side.cameras_for(arm) == []
    assert only_side.observed[part('upper_arm_l')] and only_side.cameras_for(
        part('upper_arm_l')
    ) == ['cam_side']
    for limit in (1, 2, 3):
        a = CameraSelector(BODY, CAMERAS, SelectionSettings(max_cameras_per_part=limit)).assign(
            q, q
        )
        counts = a.selected.sum(axis=1)
        assert counts.max() <= limit and (counts >= 1).all()
    every = CameraSelector(BODY, CAMERAS).assign(q, q)  # default 0: every visible camera
    visible = np.nan_to_num(every.vi, nan=-1.0) >= SelectionSettings().vi_threshold
    assert np.array_equal(every.selected, visible) and visible.sum(axis=1).max() == 3


def test_assignment_keeps_the_best_ranked_visible_cameras():
    vi = np.array([[0.9, 0.5, 0.1], [0.1, 0.0, 0.19], [0.3, 0.3, 0.3]])
    obs = np.array([[1.0, 5.0, 9.0], [3.0, 2.0, 1.0], [2.0, 2.0, 7.0]])
    selected, observed, rank = assignment(vi, obs, np.array([True, True, True]), 0.2, 2)
    assert selected.tolist() == [[True, True, False], [False, False, False], [True, False, True]]
    assert observed.tolist() == [True, False, True]
    assert rank[0].tolist() == [1, 0, -1] and rank[2].tolist() == [
        1,
        -1,
        0,
    ]  # equal observability: VI, then order
    four = np.array(
        [[0.9, 0.5, 0.3, 0.1], [0.4, 0.4, 0.4, 0.4]]
    )  # a four-camera rig, no cap: all visible
    selected, _, _ = assignment(four, np.ones((2, 4)), np.ones(4, bool), 0.2, 0)
    assert selected.tolist() == [[True, True, True, False], [True, True, True, True]]


def test_all_cameras_mode_assigns_every_live_camera_to_every_part():
    a = Assignment.all_cameras(NAMES, {'cam_side': False})
    assert a.mode == MODE_ALL_CAMERAS and a.observed.all()
    assert all(a.cameras_for(i) == ['cam_front', 'cam_top'] for i in range(len(PART_NAMES)))
    assert np.isnan(a.vi).all() and a.masks()['cam_side'].sum() == 0


@pytest.mark.parametrize(
    'bad',
    [
        {'vi_threshold': 1.5},
        {'max_cameras_per_part': -1},
        {'max_cameras_per_part': 65},
        {'render_scale': 0.0},
        {'observability_norm': 'max'},
        {'camera_timeout_s': 0.0},
    ],
)
def test_bad_settings_are_refused_with_the_reason(bad):
    name = next(iter(bad))
    with pytest.raises(ValueError, match=name.removesuffix('_s')):
        SelectionSettings(**bad)


def test_batched_label_renderer_equals_the_per_part_renderer():
    scenario = make_scenario('studio-walk', BODY)
    q, _ = scenario.coordinates(np.array([0.0, 0.7, 1.9]))
    for pose in q:
        rotations, origins = BODY.forward_kinematics(pose)
        for camera in scenario.cameras:
            for scale in (0.25, 0.5):
                a = render(camera, rotations, origins, BODY.semi_axes, BODY.lengths, scale=scale)
                b = render_labels(
                    camera, rotations, origins, BODY.semi_axes, BODY.lengths, scale=scale
                )
                assert np.array_equal(a.label, b.label) and np.array_equal(a.depth, b.depth)
                assert np.array_equal(a.unoccluded_area, b.unoccluded_area)
