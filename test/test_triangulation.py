"""Triangulation of keypoints as Pose2Sim does it; a track compared with such a reference."""

from __future__ import annotations

import numpy as np
import pytest

from memo_ros.core.evaluation.keypoints import JOINTS, compare, heading, procrustes
from memo_ros.core.evaluation.triangulation import temporal_outliers, triangulate
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.rotations import rot_z


def _ring(n: int = 4) -> list[Camera]:
    """Return ``n`` distorted cameras around the origin, 3.5 m away, looking at (0, 0, 1)."""
    cameras = []
    for k in range(n):
        angle = 2 * np.pi * k / n + 0.3
        eye = [3.5 * np.cos(angle), 3.5 * np.sin(angle), 1.6]
        cameras.append(
            Camera.look_at(
                f'cam{k}',
                eye,
                [0, 0, 1],
                width=640,
                height=480,
                fx=500.0,
                D=[-0.12, 0.03, 0.001, -0.001, 0.0],
            )
        )
    return cameras


def _project(cameras, points):
    """Return pixels (C, F, J, 2) of world points (F, J, 3)."""
    return np.stack([cam.project(points) for cam in cameras])


def test_exact_keypoints_are_triangulated_exactly_through_the_distortion():
    cameras = _ring()
    points = np.random.default_rng(0).uniform([-0.5, -0.5, 0.1], [0.5, 0.5, 1.8], (5, 12, 3))
    result = triangulate(cameras, _project(cameras, points), np.ones((4, 5, 12)))
    assert np.allclose(result.points, points, atol=1e-6)
    assert np.nanmax(result.error_px) < 1e-3 and result.used.all()


def test_a_camera_far_off_is_dropped_and_a_low_confidence_one_is_not_used():
    cameras = _ring()
    points = np.random.default_rng(1).uniform([-0.5, -0.5, 0.1], [0.5, 0.5, 1.8], (3, 12, 3))
    uv = _project(cameras, points) + np.random.default_rng(2).normal(0, 0.5, (4, 3, 12, 2))
    uv[2, :, 4] += 60.0  # cam2 sees the left wrist 60 px off (a detector's wrong limb)
    confidence = np.ones((4, 3, 12))
    confidence[3, :, 7] = 0.1  # cam3 barely sees the right hip
    result = triangulate(cameras, uv, confidence, max_error_px=10.0)
    assert not result.used[:, 4, 2].any() and result.used[:, 4, [0, 1, 3]].all()
    assert not result.used[:, 7, 3].any()
    assert np.linalg.norm(result.points - points, axis=-1).max() < 0.01
    assert np.nanmax(result.error_px) < 2.0


def test_two_cameras_are_the_least_and_one_gives_nothing():
    cameras = _ring()
    points = np.full((1, 12, 3), 0.5)
    confidence = np.zeros((4, 1, 12))
    confidence[:2] = 1.0
    confidence[1, 0, 0] = 0.0
    result = triangulate(cameras, _project(cameras, points), confidence)
    assert np.isnan(result.points[0, 0]).all()
    assert np.allclose(result.points[0, 1:], 0.5, atol=1e-6)


def _standing(facing_deg: float) -> np.ndarray:
    """Return 12 joints of a person standing at the origin, facing ``facing_deg``.

    Facing 0 degrees (+x), its left is at +y.
    """
    y = {'l': 0.18, 'r': -0.18}
    z = {'shoulder': 1.45, 'elbow': 1.15, 'wrist': 0.85, 'hip': 0.95, 'knee': 0.5, 'ankle': 0.08}
    local = np.array(
        [[0.0, y[j[-1]] * (0.6 if j[:3] in 'hipkneankl' else 1.0), z[j[:-2]]] for j in JOINTS]
    )
    local[[JOINTS.index('knee_l'), JOINTS.index('knee_r')], 0] = 0.05  # knees ahead
    return local @ rot_z(np.radians(facing_deg)).T


def test_comparison_tells_the_sides_the_heading_and_removes_offsets():
    reference = np.stack([_standing(30.0) + [0.01 * f, 0.0, 0.0] for f in range(6)])
    estimate = reference + np.array([0.02, -0.01, 0.03])  # a constant offset
    result = compare(estimate, reference)
    assert result.sides_agree.all()
    assert np.nanmax(result.offset_removed_mm) < 1e-6
    assert np.nanmax(result.procrustes_mm) < 1e-6
    assert np.nanmean(result.raw_mm) == pytest.approx(1000 * np.linalg.norm([0.02, -0.01, 0.03]))
    assert np.abs(result.heading_error_deg).max() < 1e-6
    # the offset in the body's frame: it faces 30 degrees, so world x is partly its left
    forward, left = np.radians(30.0), np.radians(120.0)
    body = [
        1000 * (0.02 * np.cos(forward) - 0.01 * np.sin(forward)),
        1000 * (0.02 * np.cos(left) - 0.01 * np.sin(left)),
        30.0,
    ]
    assert result.body_offset_mm == pytest.approx(np.tile(body, (len(JOINTS), 1)))
    summary = result.summary()['per_joint']['hip_l']
    assert [summary[f'offset_{a}_mm'] for a in ('forward', 'left', 'up')] == pytest.approx(body)
    turned = np.stack([_standing(210.0) for _ in range(6)])  # facing backwards: sides swapped
    backwards = compare(turned, np.stack([_standing(30.0)] * 6))
    assert not backwards.sides_agree.any()
    assert np.abs(backwards.heading_error_deg) == pytest.approx(180.0)


def test_legs_that_swapped_places_disagree_though_the_body_faces_the_right_way():
    reference = np.stack([_standing(30.0)] * 4)
    step = rot_z(np.radians(30.0)) @ [0.25, 0.0, 0.0]  # the left leg ahead, the right behind
    for side, sign in (('l', 1.0), ('r', -1.0)):
        reference[:, [JOINTS.index(f'knee_{side}'), JOINTS.index(f'ankle_{side}')]] += sign * step
    legs = [JOINTS.index(j) for j in ('knee_l', 'ankle_l', 'knee_r', 'ankle_r')]
    estimate = reference.copy()
    estimate[:, legs] = reference[:, [legs[2], legs[3], legs[0], legs[1]]]
    estimate[2:] = reference[2:]  # the last two frames right
    result = compare(estimate, reference)
    assert not result.turned.any()  # the body faces the right way in every frame
    assert result.limbs_swapped.tolist() == [[False, True]] * 2 + [[False, False]] * 2
    assert result.sides_agree.tolist() == [False, False, True, True]
    figures = result.summary()
    assert (figures['frames_legs_swapped'], figures['frames_arms_swapped']) == (2, 0)
    assert figures['frames_sides_disagree'] == 2 and figures['frames_turned'] == 0


def test_heading_is_where_the_left_of_the_body_is_on_the_left():
    assert np.degrees(heading(_standing(0.0))) == pytest.approx(0.0, abs=1e-9)
    assert np.degrees(heading(_standing(90.0))) == pytest.approx(90.0, abs=1e-9)


def test_procrustes_undoes_a_similarity():
    points = np.random.default_rng(4).normal(0, 0.3, (12, 3))
    moved = 1.1 * points @ rot_z(0.7).T + [0.5, -0.2, 0.1]
    assert np.allclose(procrustes(moved, points), points, atol=1e-9)


def test_procrustes_is_fitted_per_frame_on_the_joints_present():
    rng = np.random.default_rng(5)
    points = rng.normal(0, 0.3, (3, 12, 3))
    moved = np.stack([(1.0 + 0.1 * f) * p @ rot_z(0.4 * f).T + [f, 0.0, 0.0]
                      for f, p in enumerate(points)])  # fmt: skip
    weight = np.ones((3, 12))
    weight[1, 5] = 0.0
    moved[1, 5] += 5.0  # a wild joint that is marked missing does not pull the fit
    aligned = procrustes(moved, points, weight)
    assert np.allclose(np.delete(aligned[1], 5, 0), np.delete(points[1], 5, 0), atol=1e-9)
    assert np.allclose(aligned[[0, 2]], points[[0, 2]], atol=1e-9)
    mirrored = points[0] * [1.0, -1.0, 1.0]  # no rotation turns a body into its mirror image
    assert np.abs(procrustes(mirrored, points[0]) - points[0]).max() > 0.05


def test_a_reference_joint_that_jumps_for_two_frames_is_flagged():
    frames = 30
    track = np.zeros((frames, 2, 3))
    track[:, :, 0] = np.linspace(0.0, 1.5, frames)[:, None]  # walking at 3 m/s (60 frames/s)
    track[:, 1, 2] = 1.0 + 0.2 * np.sin(np.linspace(0, 6, frames))  # a swinging wrist
    track[[10, 11], 1] += [0.0, 0.8, -0.5]  # two frames of the other limb
    track[20, 0] = np.nan  # not seen
    flagged = temporal_outliers(track)
    assert flagged[[10, 11], 1].all() and flagged.sum() == 2


def test_a_track_missing_joints_is_compared_on_those_present():
    reference = np.stack([_standing(0.0)] * 4)
    reference[2, JOINTS.index('wrist_r')] = np.nan
    result = compare(reference + [0.0, 0.0, 0.05], reference)
    assert np.isnan(result.raw_mm[2, JOINTS.index('wrist_r')])
    assert np.nanmean(result.raw_mm) == pytest.approx(50.0)
    assert np.nanmax(result.procrustes_mm) < 1e-6 and result.sides_agree.all()
