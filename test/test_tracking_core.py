"""The tracker's science without DDS.

Motion model, Jacobian L, force assignment, information-form EKF, track states.
"""

from __future__ import annotations

import numpy as np
import pytest

from memo_ros.core.geometry.body import PART_NAMES, load_studio_actor
from memo_ros.core.geometry.render import render
from memo_ros.core.geometry.rotations import rotvec_to_matrix
from memo_ros.core.multiview.correspondence import (
    Candidates,
    ContourRays,
    assign_forces,
    contour_rays,
    on_outline,
    outline_candidates,
    ray_part_hits,
    rig_on_outline,
    rig_outline_candidates,
    thinned_samples,
)
from memo_ros.core.multiview.ekf import ArticulatedEKF, Measurements
from memo_ros.core.multiview.kinematic_jacobian import (
    chain_axes,
    point_jacobian,
    projected_rows,
)
from memo_ros.core.multiview.model_nodes import fan_alignment, model_nodes
from memo_ros.core.multiview.motion import (
    ConstantVelocity,
    coordinate_rates,
    coordinates_from_names,
    local_difference,
    retract,
    right_jacobian,
    tangent_rates,
)
from memo_ros.core.multiview.tracking import (
    LOST,
    TRACKING,
    WAITING,
    ArticulatedTracker,
    FirstOutline,
    TrackerSettings,
    sample_spacing,
)
from memo_ros.core.simulation.scenarios import make_scenario
from memo_ros.core.vision.contours import occluding_contours, silhouette_outlines

BODY = load_studio_actor()


def _silhouette_contours(cameras, q):
    """Return what a perfect contour_node sees.

    The outer outline of the rendered body, smoothed and sampled.
    """
    rotations, origins = BODY.forward_kinematics(q)
    tables = {}
    for cam in cameras:
        label = render(cam, rotations, origins, BODY.semi_axes, BODY.lengths).label
        tables[cam.name] = occluding_contours(silhouette_outlines(label > 0))
    return tables


def _random_pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return BODY.neutral() + rng.normal(0.0, 0.4, BODY.n_coordinates)


def test_right_jacobian_and_increments_are_exact():
    r = np.array([0.7, -1.1, 0.4])
    dr = 1e-6 * np.array([1.0, 2.0, -1.0])
    assert np.allclose(
        rotvec_to_matrix(r + dr),
        rotvec_to_matrix(r) @ rotvec_to_matrix(right_jacobian(r) @ dr),
        atol=1e-11,
    )
    model = ConstantVelocity(BODY)
    q, qdot = _random_pose(1), np.random.default_rng(2).normal(0, 1, BODY.n_coordinates)
    assert np.allclose(
        local_difference(retract(q, 0.1 * qdot, model.groups), q, model.groups), 0.1 * qdot
    )
    assert np.allclose(
        coordinate_rates(q, tangent_rates(q, qdot, model.groups), model.groups), qdot
    )
    q_next, _ = model.predict_coordinates(q, qdot, 1e-5)
    assert np.allclose(
        (q_next - q) / 1e-5, qdot, atol=1e-4
    )  # the selector's prediction is q + q' dt


def test_coordinates_from_names_refuses_unknown_names():
    q = coordinates_from_names(BODY, ['root_tx', 'gait_phase'], [1.5, 0.3])
    assert q[0] == 1.5
    with pytest.raises(KeyError):
        coordinates_from_names(BODY, ['elbow_q'], [0.0])


def test_point_jacobian_matches_finite_differences_of_forward_kinematics():
    q = _random_pose(3)
    groups = ConstantVelocity(BODY).groups
    rotations, origins = BODY.forward_kinematics(q)
    local = np.random.default_rng(4).normal(0, 0.1, (len(PART_NAMES), 3))
    points = np.einsum('pij,pj->pi', rotations, local) + origins
    L = point_jacobian(chain_axes(BODY, q, rotations, origins), np.arange(len(PART_NAMES)), points)
    h = 1e-6
    for c in range(BODY.n_coordinates):
        delta = np.zeros(BODY.n_coordinates)
        delta[c] = h
        r2, o2 = BODY.forward_kinematics(retract(q, delta, groups))
        moved = np.einsum('pij,pj->pi', r2, local) + o2
        assert np.allclose((moved - points) / h, L[:, :, c], atol=1e-5), BODY.coordinate_names[c]


def test_projected_rows_equal_the_point_jacobian_contracted_with_g():
    q = _random_pose(6)
    rotations, origins = BODY.forward_kinematics(q)
    rng = np.random.default_rng(7)
    parts = rng.integers(0, len(PART_NAMES), 50)
    points = origins[parts] + rng.normal(0, 0.2, (50, 3))
    g = rng.normal(0, 1, (50, 3))
    chain = chain_axes(BODY, q, rotations, origins)
    expected = np.einsum('ni,nij->nj', g, point_jacobian(chain, parts, points))
    assert np.allclose(projected_rows(chain, parts, points, g), expected, atol=1e-12)


def test_ray_part_hits_find_the_renderers_nearest_part_and_depth():
    scenario = make_scenario('studio-arm', BODY)
    q, _ = scenario.coordinates(np.array([1.0]))
    rotations, origins = BODY.forward_kinematics(q[0])
    for cam in scenario.cameras:
        image = render(cam, rotations, origins, BODY.semi_axes, BODY.lengths)
        rays = cam.pixel_grid_rays()[::3, ::3].reshape(
            -1, 3
        )  # pixel centres, as the renderer casts them
        ray, part, dist = ray_part_hits(
            [cam], np.zeros(len(rays), int), rays, rotations, origins, BODY.semi_axes, BODY.lengths
        )
        nearest = np.full(len(rays), np.inf)
        np.minimum.at(nearest, ray, dist)
        label = np.zeros(len(rays), int)
        first = dist == nearest[ray]
        label[ray[first]] = part[first] + 1
        expected = image.label[::3, ::3].reshape(-1)
        agree = label == expected
        assert expected.any() and agree.mean() > 0.999, (
            cam.name
        )  # grazing rays may round either way
        depth = nearest * (rays @ cam.R_world_cam[:, 2])
        seen = agree & (label > 0)
        assert np.allclose(depth[seen], image.depth[::3, ::3].reshape(-1)[seen], rtol=1e-5), (
            cam.name
        )


def test_rig_batches_equal_the_per_camera_candidates_and_outline_tests():
    scenario = make_scenario('studio-walk', BODY)
    q, _ = scenario.coordinates(np.array([0.7]))
    rotations, origins = BODY.forward_kinematics(q[0])
    nodes = model_nodes(BODY)
    cams = scenario.cameras
    rig = rig_outline_candidates(cams, nodes, rotations, origins)
    keys = [np.sort(c.key)[::2] for c in rig]
    for k, cam in enumerate(cams):
        for batch, single in (
            (rig[k], outline_candidates(cam, nodes, rotations, origins)),
            (
                rig_outline_candidates(cams, nodes, rotations, origins, keys)[k],
                outline_candidates(cam, nodes, rotations, origins, keys[k]),
            ),
        ):
            for name in ('part', 'points', 'normal', 'cap', 'rim', 'uv', 'key'):
                assert np.array_equal(getattr(batch, name), getattr(single, name)), (
                    cam.name,
                    name,
                )
    flags = rig_on_outline(cams, rig, rotations, origins, BODY.semi_axes, BODY.lengths)
    lazy = FirstOutline(cams, rig, rotations, origins, BODY, 2.0)
    some = [np.arange(0, len(c), 3) for c in rig]
    for k, cam in enumerate(cams):
        single = on_outline(cam, rig[k], rotations, origins, BODY.semi_axes, BODY.lengths)
        assert np.array_equal(flags[k], single) and 0 < single.sum() < len(single), cam.name
        assert np.array_equal(lazy.usable(some)[k], single[some[k]])  # tested on demand ...
    assert all(
        np.array_equal(u, f) for u, f in zip(lazy.usable([np.arange(len(c)) for c in rig]), flags)
    )  # ... or all


def _reference_assignment(rays, cand, epsilon, gate):
    """Brute force Steps 2-3.

    Per sample, the first of its 8 nearest candidates within the gate passing eq. 13.
    """
    out = []
    for s, uv in enumerate(rays.uv):
        d = np.hypot(*(cand.uv - uv).T)
        for c in np.argsort(d)[:8]:
            if d[c] >= gate:
                break
            side = cand.normal[c] @ rays.k[s]
            fan = fan_alignment(cand.normal[c : c + 1], cand.cap[c : c + 1], rays.k[s : s + 1])[0]
            if (fan if cand.rim[c] else side) >= epsilon[cand.part[c]]:
                if cand.usable is None or cand.usable[c]:
                    out.append((s, c))
                break
    return out


def test_assignment_takes_the_first_compatible_of_the_eight_nearest_candidates():
    rng = np.random.default_rng(8)
    n_s, n_c = 400, 300

    def unit(a: np.ndarray) -> np.ndarray:
        return a / np.linalg.norm(a, axis=1, keepdims=True)

    rays = ContourRays(
        rng.uniform(0, 200, (n_s, 2)),
        unit(rng.normal(0, 1, (n_s, 2))),
        unit(rng.normal(0, 1, (n_s, 3))),
    )
    rim = rng.random(n_c) < 0.5
    cand = Candidates(
        rng.integers(0, 4, n_c),
        rng.normal(0, 1, (n_c, 3)),
        unit(rng.normal(0, 1, (n_c, 3))),
        np.where(rim[:, None], unit(rng.normal(0, 1, (n_c, 3))), 0.0),
        rim,
        rng.uniform(0, 200, (n_c, 2)),
    )
    epsilon = np.array([0.9, 0.5, 0.0, -0.5])
    m = assign_forces(rays, cand, epsilon, 12.0)
    reference = _reference_assignment(rays, cand, epsilon, 12.0)
    assert 0 < len(reference) < n_s and list(zip(m.sample, m.node)) == reference
    cand.usable = rng.random(n_c) < 0.7
    m = assign_forces(rays, cand, epsilon, 12.0)
    assert list(zip(m.sample, m.node)) == _reference_assignment(rays, cand, epsilon, 12.0)


def test_samples_within_a_radius_agree_with_the_kd_tree():
    rng = np.random.default_rng(9)
    rays = ContourRays(rng.uniform(100, 300, (500, 2)), np.zeros((500, 2)), np.zeros((500, 3)))
    points = rng.uniform(0, 400, (3000, 2))
    for radius in (3.0, 12.5, 50.0):
        expected = np.isfinite(rays.tree.query(points, k=1, distance_upper_bound=radius)[0])
        assert np.array_equal(rays.within(points, radius), expected) and 0 < expected.sum() < len(
            points
        )


def test_force_assignment_at_the_true_pose_leaves_subpixel_residuals_and_matching_normals():
    scenario = make_scenario('studio-arm', BODY)
    q, _ = scenario.coordinates(np.array([1.0]))
    rotations, origins = BODY.forward_kinematics(q[0])
    tables = _silhouette_contours(scenario.cameras, q[0])
    nodes = model_nodes(BODY)
    for cam in scenario.cameras:
        rays = contour_rays(cam, tables[cam.name])
        cand = outline_candidates(
            cam, nodes, rotations, origins
        )  # on the outline by the exact ray test
        cand = cand.subset(on_outline(cam, cand, rotations, origins, BODY.semi_axes, BODY.lengths))
        m = assign_forces(rays, cand, nodes.epsilon, 25.0)
        assert len(m.sample) > 0.9 * len(rays.uv)
        r = np.einsum('ni,ni->n', rays.outward[m.sample], rays.uv[m.sample] - cand.uv[m.node])
        assert np.median(np.abs(r)) < 0.3 and np.percentile(np.abs(r), 95) < 1.5, cam.name
        side = ~cand.rim[m.node]
        # eq. 13 with the plane normal k_z oriented out of the silhouette, like the surface normal
        assert (
            np.median(np.einsum('ni,ni->n', rays.k[m.sample][side], cand.normal[m.node][side]))
            > 0.99
        )


def test_information_form_update_equals_the_covariance_form_for_a_linear_measurement():
    model = ConstantVelocity(BODY)
    ekf = ArticulatedEKF(model)
    n = BODY.n_coordinates
    rng = np.random.default_rng(5)
    ekf.initialize(np.zeros(n), None, rng.uniform(0.05, 0.2, n), 0.5)
    ekf.q[3:6] = 0.0
    H = np.zeros((40, n))
    H[:, 6:] = rng.normal(0, 1, (40, n - 6))  # joints only: additive coordinates, linear model
    truth = np.zeros(n)
    truth[6:] = rng.normal(0, 0.1, n - 6)
    z = H @ truth
    P = ekf.P.copy()
    HP = np.hstack([H, np.zeros((40, n))])
    S = HP @ P @ HP.T + 0.01**2 * np.eye(40)
    expected = (P @ HP.T @ np.linalg.solve(S, z))[:n]
    ekf.update(lambda q: Measurements(H, z - H @ q, np.full(40, 0.01)), iterations=1, gate=1e9)
    assert np.allclose(ekf.q, expected, atol=1e-8)


def test_robust_weights_stop_a_few_outlying_measurements_dragging_the_estimate():
    n = BODY.n_coordinates
    rng = np.random.default_rng(7)
    H = np.zeros((300, n))
    H[:, 6:] = rng.normal(0, 1, (300, n - 6))
    truth = np.zeros(n)
    truth[6:] = rng.normal(0, 0.1, n - 6)
    z = H @ truth + rng.normal(0, 0.01, 300)
    z[:30] += 0.5  # a tenth of the measurements 50 sigma off (a segmentation fault)
    sigma = np.full(300, 0.01)

    def estimate(robust: np.ndarray | None) -> np.ndarray:
        ekf = ArticulatedEKF(ConstantVelocity(BODY))
        ekf.initialize(np.zeros(n), None, 1.0, 0.5)
        ekf.update(lambda q: Measurements(H, z - H @ q, sigma, robust), iterations=6, gate=1e9)
        return ekf.q

    plain, robust = estimate(None), estimate(sigma)
    assert np.abs(robust - truth).max() < 0.2 * np.abs(plain - truth).max()
    assert np.allclose(estimate(np.full(300, np.inf)), plain)  # an infinite scale: plain rows


def test_tracker_follows_the_moving_arm_from_perfect_silhouettes():
    scenario = make_scenario('studio-arm', BODY, frames=20)
    times = np.arange(20) / scenario.frame_rate
    q_true, _ = scenario.coordinates(times)
    tracker = ArticulatedTracker(BODY, scenario.cameras, initial_pose=q_true[0])
    errors = []
    for k, t in enumerate(times):
        result = tracker.step(int(t * 1e9), _silhouette_contours(scenario.cameras, q_true[k]))
        assert result.status == TRACKING
        rotations, origins = BODY.forward_kinematics(q_true[k])
        errors.append(1000 * np.linalg.norm(result.origins - origins, axis=1).mean())
    assert np.mean(errors) < 10.0, errors


def test_thinning_keeps_every_contour_evenly_and_within_the_budget():
    scenario = make_scenario('studio-arm', BODY, frames=1)
    q, _ = scenario.coordinates(np.zeros(1))
    table = _silhouette_contours(scenario.cameras, q[0])['cam_front']
    assert len(table) > 600
    thin = thinned_samples(table, 300)
    assert 150 < len(thin) <= 300
    assert set(np.unique(thin['contour'])) == set(np.unique(table['contour']))
    # every k-th sample of each contour: the spacing grows by k, the samples stay in order
    ratio = sample_spacing(thin) / sample_spacing(table)
    assert ratio == pytest.approx(np.ceil(len(table) / 300), rel=0.1)
    assert thinned_samples(table, 0) is table and thinned_samples(table, len(table)) is table


def test_a_thinned_intake_tracks_the_moving_arm_as_the_whole_one():
    """samples_per_camera takes every 3rd or 4th sample here: the track stays within a few mm."""
    scenario = make_scenario('studio-arm', BODY, frames=20)
    times = np.arange(20) / scenario.frame_rate
    q_true, _ = scenario.coordinates(times)
    frames = [_silhouette_contours(scenario.cameras, q) for q in q_true]
    errors = {}
    for budget in (0, 300):
        settings = TrackerSettings(samples_per_camera=budget)
        tracker = ArticulatedTracker(BODY, scenario.cameras, settings, initial_pose=q_true[0])
        errors[budget] = []
        for k, t in enumerate(times):
            result = tracker.step(int(t * 1e9), frames[k])
            assert result.status == TRACKING
            if budget and k:  # the start (frame 0) weighs whole contours
                assert result.samples <= 300 * len(scenario.cameras)
            origins = BODY.forward_kinematics(q_true[k])[1]
            errors[budget].append(1000 * np.linalg.norm(result.origins - origins, axis=1).mean())
    assert np.mean(errors[300]) < 10.0 and np.mean(errors[300]) < np.mean(errors[0]) + 2.0, errors


def test_no_contours_loses_the_track_and_contours_bring_it_back():
    scenario = make_scenario('studio-arm', BODY, frames=10)
    q0, _ = scenario.coordinates(np.zeros(1))
    settings = TrackerSettings(lost_after=3)
    tracker = ArticulatedTracker(BODY, scenario.cameras, settings, initial_pose=q0[0])
    assert (
        tracker.step(
            0, {c.name: np.zeros(0, dtype=[('x', 'f4')]) for c in scenario.cameras}
        ).status
        == WAITING
    )
    contours = _silhouette_contours(scenario.cameras, q0[0])
    assert tracker.step(1, contours).status == TRACKING
    states = [tracker.step(2 + k, {}).status for k in range(3)]
    assert states == [TRACKING, TRACKING, LOST]
    back = tracker.step(10, contours)
    assert back.status == TRACKING and back.initialised


def test_set_pose_refuses_non_finite_values():
    tracker = ArticulatedTracker(BODY, make_scenario('studio-arm', BODY).cameras)
    q = BODY.neutral()
    q[4] = np.nan
    with pytest.raises(ValueError):
        tracker.set_pose(q)


def test_a_search_due_while_the_tracker_is_behind_waits_for_a_frame_that_can_afford_it():
    """A look at the twin due while newer frames wait is put off (counted), then taken."""
    scenario = make_scenario('studio-arm', BODY, frames=9)
    times = np.arange(9) / scenario.frame_rate
    q_true, _ = scenario.coordinates(times)
    settings = TrackerSettings(twin_recheck=3)
    tracker = ArticulatedTracker(BODY, scenario.cameras, settings, initial_pose=q_true[0])
    refits: list[int] = []
    refit = tracker._refit
    tracker._refit = lambda *args, **kwargs: refits.append(1) or refit(*args, **kwargs)
    deferred = []
    for k, t in enumerate(times):
        behind = 0 < k < 8  # frame 0 is the start, which always searches
        result = tracker.step(
            int(t * 1e9),
            _silhouette_contours(scenario.cameras, q_true[k]),
            None,
            lambda: not behind,
        )
        assert result.status == TRACKING
        deferred.append(result.searches_deferred)
        if k == 0:
            refits.clear()
        if k == 7:
            assert not refits, 'a look ran while the tracker was behind'
    assert deferred[7] >= 5  # the look was due from frame 3 on, asked again every frame
    assert refits, 'the look due since frame 3 did not run once the tracker caught up'
    assert deferred[8] == deferred[7]


def test_a_frame_updated_with_fewer_iterations_relinearises_fewer_times():
    """step(..., iterations=1) linearises the measurement once; the settings' 2 otherwise."""
    scenario = make_scenario('studio-arm', BODY, frames=3)
    times = np.arange(3) / scenario.frame_rate
    q_true, _ = scenario.coordinates(times)
    tracker = ArticulatedTracker(BODY, scenario.cameras, TrackerSettings(), initial_pose=q_true[0])
    tables = [_silhouette_contours(scenario.cameras, q_true[k]) for k in range(3)]
    tracker.step(0, tables[0], None, lambda: False)
    calls: list[int] = []
    measurement = tracker._measurement_function

    def counted(*args):
        measure = measurement(*args)
        return lambda q: calls.append(1) or measure(q)

    tracker._measurement_function = counted
    for k, iterations in ((1, 1), (2, None)):
        calls.clear()
        result = tracker.step(int(times[k] * 1e9), tables[k], None, lambda: False, iterations)
        assert result.status == TRACKING
        assert len(calls) == (iterations or TrackerSettings().iterations), (k, len(calls))


def _tracked_through_gaps(scenario, q_true, frames, gap: float) -> tuple[list[float], int]:
    """Track ``frames`` of the scenario from perfect silhouettes.

    The MPJPE (mm) of each (1 m where the track was lost), and how many frames after a gap
    started from the moved last pose.
    """
    tracker = ArticulatedTracker(
        BODY, scenario.cameras, TrackerSettings(reacquire_gap=gap), initial_pose=q_true[0]
    )
    errors = []
    for k in frames:
        contours = _silhouette_contours(scenario.cameras, q_true[k])
        result = tracker.step(int(k / scenario.frame_rate * 1e9), contours)
        if result.status != TRACKING:  # lost (the next frame starts again): scored 1 m
            errors.append(1000.0)
            continue
        _, origins = BODY.forward_kinematics(q_true[k])
        errors.append(1000 * np.linalg.norm(result.origins - origins, axis=1).mean())
    return errors, tracker.reacquisitions


def test_after_a_gap_a_walk_starts_from_the_last_pose_moved_with_the_silhouettes():
    """A live tracker that skipped a second of a walk (a slow start, a search) finds the legs.

    Over the gap the constant-velocity guess carries each leg's swing through its range; the
    last pose moved as far as the silhouettes' centre moved fits better and is kept.
    """
    scenario = make_scenario('studio-walk', BODY)
    q_true, _ = scenario.coordinates(np.arange(80) / scenario.frame_rate)
    frames = [k for k in range(80) if not 20 < k < 50]  # 1 s without a frame
    guessed, none = _tracked_through_gaps(scenario, q_true, frames, gap=0.0)
    moved, reacquired = _tracked_through_gaps(scenario, q_true, frames, gap=0.25)
    after = frames.index(50)
    assert none == 0 and reacquired == 1 and max(moved) < 250.0
    assert np.mean(moved[after:]) < 0.6 * np.mean(guessed[after:]), (guessed, moved)
    assert moved[:after] == pytest.approx(guessed[:after])  # no gap, no change
