"""Rohr's walker in the ROS-free core.

Eq. 2-6, visible model contours, eq. 7-11, the two-lines rule, the Kalman filter (eq. 12-22) and
the initialization on simulated street frames.
"""

from __future__ import annotations

import numpy as np
import pytest

from memo_ros.core.evaluation.metrics import phase_error
from memo_ros.core.geometry.body import PART_NAMES, Body, load_studio_actor
from memo_ros.core.geometry.render import render
from memo_ros.core.simulation.imaging import (
    ImagingOptions,
    background_image,
    compose_frame,
)
from memo_ros.core.simulation.scenarios import line_walk, make_scenario, street_camera
from memo_ros.core.vision.contours import ContourPipeline
from memo_ros.core.walking.ground import (
    outline_midpoints,
    position_on_ground,
    rectangle_offsets,
)
from memo_ros.core.walking.initialisation import two_lines
from memo_ros.core.walking.kalman import KalmanParams, WalkingKalman, transition
from memo_ros.core.walking.model_contours import visible_contours
from memo_ros.core.walking.position import (
    position_from_box,
    projection_matrix,
    rohr_system,
)
from memo_ros.core.walking.search import WalkerModel, grid_offsets
from memo_ros.core.walking.similarity import (
    SimilarityParams,
    candidate_edges,
    similarity,
)
from memo_ros.core.walking.tracker import TRACKING, WalkerSettings, WalkingTracker
from memo_ros.nodes.contour_node import pipeline_settings


@pytest.fixture(scope='module')
def body():
    return load_studio_actor()


@pytest.fixture(scope='module')
def camera():
    return street_camera()[0]


# ------------------------------------------------------------------ eq. 2-6
def test_eq_2_6_recover_the_sole_from_an_exact_box(camera):
    sole = np.array([0.7, 0.4, 0.0])
    height = 1.74
    bottom, top = camera.project(np.array([sole, sole + [0.0, 0.0, height]]))
    found = position_from_box(camera, bottom, top, height)
    assert np.allclose(found.sole, sole, atol=1e-6)
    assert np.allclose(found.top, sole + [0.0, 0.0, height], atol=1e-6)


def test_eq_2_6_shift_the_midpoints_so_the_last_three_rows_hold_exactly(camera):
    sole = np.array([-0.9, -0.2, 0.0])
    height = 1.74
    bottom, top = camera.project(np.array([sole, sole + [0.0, 0.0, height]]))
    top_skewed = top + [3.0, 0.0]  # a rectangle whose top midpoint is off the vertical
    T = projection_matrix(camera)
    t_star, b_star = rohr_system(T, bottom, top_skewed, height)
    x_star = np.linalg.lstsq(t_star, -b_star, rcond=None)[0]
    assert np.abs((t_star @ x_star + b_star)[3:]).max() > 1e-3  # measured midpoints: inconsistent
    found = position_from_box(camera, bottom, top_skewed, height)
    t_star, b_star = rohr_system(T, found.bottom_px, found.top_px, height)
    x_star = np.concatenate([found.sole, [found.h_u, found.h_o]])
    residual = t_star @ x_star + b_star
    assert np.abs(residual).max() < 1e-9 * np.abs(b_star).max()  # all six rows of eq. 6 hold
    assert (
        np.linalg.norm(found.bottom_px - bottom) < 2.0
    )  # both midpoints moved by about half the skew
    assert abs(found.sole[2]) < 0.01 and np.linalg.norm(found.sole[:2] - sole[:2]) < 0.03


def test_eq_2_6_refuses_a_flat_box(camera):
    with pytest.raises(ValueError, match='no height'):
        position_from_box(camera, [320.0, 300.0], [320.0, 300.0], 1.75)


# ------------------------------------------------------- depth from the ground
def test_ground_gives_the_sole_and_the_height_of_an_exact_box(camera):
    for sole, height in (([0.7, 0.4, 0.0], 1.60), ([-1.2, -0.3, 0.0], 1.88)):
        sole = np.array(sole)
        bottom, top = camera.project(np.array([sole, sole + [0.0, 0.0, height]]))
        found = position_on_ground(camera, bottom, top)
        assert np.allclose(found.sole, sole, atol=1e-6) and found.height == pytest.approx(height)
        # a rectangle half a pixel off in its bottom row: about 4 cm of depth at 11 m, no height
        # needed
        found = position_on_ground(camera, bottom + [0.0, 0.5], top)
        assert 0.01 < np.linalg.norm(found.sole - sole) < 0.06
        assert found.height == pytest.approx(height, abs=0.01)
    on_a_step = position_on_ground(camera, bottom, top, ground_z=0.2)  # another ground plane
    assert on_a_step.sole[2] == 0.2 and on_a_step.sole[1] < sole[1] - 1.0


def test_ground_refuses_a_bottom_above_the_horizon(camera):
    horizon = camera.project(np.array([[0.0, 1e6, camera.centre[2]]]))[0]
    with pytest.raises(ValueError, match='behind the camera|parallel'):
        position_on_ground(camera, horizon - [0.0, 5.0], horizon - [0.0, 200.0])


def test_model_outline_rectangle_is_the_rendered_one_and_lies_below_the_pelvis(body, camera):
    model = WalkerModel(body, camera)
    for pose in (0.0, 0.25, 0.5, 0.75):
        rotations, origins = body.forward_kinematics(model.coordinates(0.3, 0.0, 0.0, pose))
        bottom, top = outline_midpoints(camera, body, rotations, origins)
        label = render(camera, rotations, origins, body.semi_axes, body.lengths).label
        rows = np.flatnonzero(label.any(axis=1))
        assert abs(bottom[1] - (rows[-1] + 0.5)) < 1.0 and abs(top[1] - (rows[0] - 0.5)) < 1.0
        offsets = rectangle_offsets(camera, body, rotations, origins)
        # the rectangle's sole is a foot's rim, within a foot's length and the hips' width
        assert np.linalg.norm(offsets.pelvis_from_sole[:2]) < 0.2
        assert offsets.rectangle_height == pytest.approx(body.standing_height(), abs=0.05)


def _scaled_body(body: Body, height: float) -> Body:
    """Return the body scaled uniformly to the standing height ``height``: another person."""
    s = height / body.standing_height()
    data = body.to_dict()
    for part in data['parts'].values():
        part['length'] *= s
        part['semi_axes'] = [s * a for a in part['semi_axes']]
    data['joints'] = {j: [s * v for v in offset] for j, offset in data['joints'].items()}
    return Body.from_dict(data)


@pytest.mark.parametrize('height', [1.60, 1.88])
def test_ground_gives_the_depth_and_height_of_a_person_it_was_not_told(body, camera, height):
    settings = pipeline_settings(make_scenario('street-walk', body).contour_parameters)
    background, frames, _ = _street_frames(_scaled_body(body, height), camera, 5, 14)
    pipeline = ContourPipeline(settings)
    pipeline.set_background(background)
    seen = []
    for grey in frames:
        out = pipeline.process(grey)
        x, y, w, h = out.box
        seen.append((np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]]), out.edges))
    depth, measured = {}, None
    for depth_from in ('ground', 'height'):  # the walker's model is the default 1.75 m body
        tracker = WalkingTracker(body, camera, WalkerSettings(depth_from=depth_from))
        for k, (corners, edges) in enumerate(seen):
            result = tracker.step(1_000_000_000 + k * 40_000_000, corners, edges)
        assert tracker.state == TRACKING
        depth[depth_from] = result.estimate[4]  # the path is at depth 0
        measured = measured or tracker.body_height
    distance = float(np.hypot(*camera.centre[:2]))  # 11 m
    print(
        f'{height} m person, 1.75 m model: depth error from the ground {depth["ground"]:+.3f} m, '
        f'from the assumed height {depth["height"]:+.3f} m; height measured {measured:.3f} m'
    )
    assert abs(depth['ground']) <= 0.005 * distance, depth  # half the 1 % target
    assert abs(depth['height']) > 0.03 * distance, depth  # the assumed height is wrong
    assert measured == pytest.approx(height, abs=0.02)


# -------------------------------------------------------- model contours
def test_visible_contours_lie_on_label_boundaries_and_hide_the_far_arm(body, camera):
    model = WalkerModel(body, camera)
    q = model.coordinates(0.0, 0.0, 0.0, 0.3)
    rotations, origins = body.forward_kinematics(q)
    contours, rendering = visible_contours(
        camera, rotations, origins, body.semi_axes, body.lengths
    )
    a, b = contours.project(camera)
    mid = ((a + b) / 2.0)[0]
    label = rendering.label
    for (u, v), part in zip(np.rint(mid).astype(int), contours.part):
        window = label[v - 2 : v + 3, u - 2 : u + 3]
        assert (window == part + 1).any() and (window != part + 1).any(), PART_NAMES[part]
    length = np.linalg.norm(b - a, axis=-1)[0]
    visible = {p: length[contours.part == i].sum() for i, p in enumerate(PART_NAMES)}
    # camera on the walker's right: the left upper arm is behind the torso, the right one in front
    assert visible['upper_arm_l'] < 0.3 * visible['upper_arm_r']


# -------------------------------------------------------------- eq. 7-11
def test_similarity_is_one_for_edges_on_the_contours_and_peaks_at_the_true_shift(body, camera):
    model = WalkerModel(body, camera)
    contours = model.contours(0.3, 0.0, 0.0, 0.6)
    a, b = contours.project(camera)
    edges = np.hstack([a[0], b[0], np.ones((len(a[0]), 1))])  # perfect edge lines
    params = SimilarityParams()
    pair = candidate_edges(a[0], b[0], edges, 0.0, params)
    assert similarity(a, b, edges, *pair, params)[0] == pytest.approx(
        1.0, abs=1e-5
    )  # l = l_M, d = 0, dphi = 0
    dx = grid_offsets(0.1, 0.02)
    offsets = np.stack([dx, np.zeros_like(dx), np.zeros_like(dx)], 1)
    sa, sb = contours.project(camera, offsets)
    pair = candidate_edges(a[0], b[0], edges, 15.0, params)
    scores = similarity(sa, sb, edges, *pair, params)
    assert np.argmax(scores) == len(dx) // 2 and np.all(np.diff(scores[len(dx) // 2 :]) < 0)


def test_eq_7_for_one_cut_edge():
    params = SimilarityParams(c_l=0.4, c_d=0.5, c_r=0.2, sigma_phi=0.25)
    a, b = np.array([[[0.0, 0.0]]]), np.array([[[50.0, 0.0]]])  # model contour, l_M = 50
    edges = np.array([[30.0, 2.0, 80.0, 2.0, 1.0]])  # parallel, 2 px away, overlaps 20 px
    s = similarity(a, b, edges, np.array([0]), np.array([0]), params)[0]
    l_e, l_m, d, r = 20.0, 50.0, 2.0, 10.0  # l_e: the length the edge overlaps the contour
    expected = (
        l_e * np.exp(-0.5 * (((l_m - l_e) / (0.4 * l_m)) ** 2 + (d / (0.5 * r)) ** 2)) / l_m
    )  # eq. 7, 11
    assert s == pytest.approx(expected, rel=1e-5)


# ------------------------------------------------------- two lines, Kalman
def test_two_lines_rule_by_count_and_by_similarity():
    k = np.arange(2, 15, dtype=float)
    true = np.mod(0.3 + 0.04 * k, 1.0)
    flipped = np.mod(true + 0.5, 1.0)
    # few displaced estimates: the larger line wins
    poses = np.where(k % 5 == 0, flipped, true)
    choice = two_lines(k, poses, np.ones_like(k))
    assert choice.rule == 'count' and choice.counts == (11, 2)
    assert phase_error(choice.phase0 + choice.slope * 14, true[-1]) < 1e-6
    # many displaced estimates of lower similarity: the line with the higher mean similarity wins
    poses = np.where(k % 2 == 0, flipped, true)
    sims = np.where(k % 2 == 0, 0.2, 0.3)
    choice = two_lines(k, poses, sims)
    assert (
        choice.rule == 'similarity'
        and phase_error(choice.phase0 + choice.slope * 14, true[-1]) < 1e-6
    )


def test_kalman_eq_12_22_holds_depth_and_smooths(body):
    phi = transition(1.0)
    assert np.allclose(phi @ np.arange(8.0), [1, 1, 5, 3, 9, 5, 13, 7])  # eq. 19
    rng = np.random.default_rng(3)
    f = WalkingKalman(np.array([0.0, 0.064, 0.0, 0.0, 11.0, 0.0, 0.0, 0.04]), KalmanParams())
    raw, smooth = [], []
    for k in range(1, 60):
        f.predict()
        z = np.array(
            [
                0.064 * k + rng.normal(0, 0.02),
                rng.normal(0, 0.01),
                12.0,
                0.04 * k + rng.normal(0, 0.02),
            ]
        )
        p, _ = f.update(z)
        raw.append(z[[0, 3]])
        smooth.append(p[[0, 6]])
        assert p[4] == 11.0 and p[3] == 0.0  # Z and Y' held
    raw, smooth = np.diff(raw, axis=0), np.diff(smooth, axis=0)
    assert np.all(smooth.var(axis=0) < 0.2 * raw.var(axis=0))


# ------------------------------------------------------------ initialization
def _street_frames(body, camera, seed: int, images: int):
    """Grey frames of a pedestrian starting at a random phase and place, and the true phases."""
    rng = np.random.default_rng(seed)
    phase0, start = rng.uniform(0.0, 1.0), rng.uniform(-1.4, -0.8)
    trajectory = line_walk(body, start=start, speed=1.6, cycle_length=1.6, phase0=phase0)
    q, phase = trajectory(np.arange(images) / 25.0)
    background = background_image(camera, seed)
    options = ImagingOptions(seed=seed)
    frames = []
    for k in range(images):
        rendering = render(
            camera, *body.forward_kinematics(q[k]), body.semi_axes, body.lengths, normals=True
        )
        frames.append(compose_frame(background, rendering, camera, options, k, rng))
    return np.clip(np.rint(background), 0, 255).astype(np.uint8), frames, phase


def test_initialization_picks_the_right_half_cycle(body, camera):
    settings = pipeline_settings(make_scenario('street-walk', body).contour_parameters)
    right, report = 0, []
    for seed in range(10):
        background, frames, phase = _street_frames(body, camera, seed, 14)
        pipeline = ContourPipeline(settings)
        pipeline.set_background(background)
        tracker = WalkingTracker(body, camera)
        for k, grey in enumerate(frames):
            out = pipeline.process(grey)
            x, y, w, h = out.box
            result = tracker.step(
                1_000_000_000 + k * 40_000_000,
                np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]]),
                out.edges,
            )
        assert tracker.state == TRACKING
        error = float(phase_error(np.mod(result.estimate[6], 1.0), phase[-1]))
        right += error < 0.1
        report.append(
            f'seed {seed}: phase error {error:.3f} ({result.choice.rule}, {result.choice.counts})'
        )
    print(f'initialization: right half-cycle on {right} of 10 seeds\n' + '\n'.join(report))
    assert right >= 9, '\n'.join(report)
