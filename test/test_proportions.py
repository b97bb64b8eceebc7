"""A person's shoulder width and upper arms, measured over the first tracked frames."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from memo_ros.core.geometry.body import Body, load_default_body
from memo_ros.core.multiview.body_estimation import scaled_body
from memo_ros.core.multiview.proportions import (
    FACTORS,
    least_of_parabola,
    shoulder_width,
    upper_arm_length,
    with_shoulder_width,
    with_upper_arm_length,
)
from memo_ros.core.multiview.tracking import TRACKING, ArticulatedTracker, TrackerSettings
from memo_ros.core.simulation.scenarios import make_scenario
from memo_ros.tools.benchmarks.dance import _contour_frames

ROOT = Path(__file__).resolve().parent.parent
NARROW = Body.from_yaml(ROOT / 'docs' / 'bodies' / 'narrow_shoulders.yaml')


def test_the_shoulder_joints_move_across_the_torso_and_nothing_else_does():
    body = scaled_body(load_default_body(), 1.75)
    narrow = with_shoulder_width(body, 0.9)
    assert shoulder_width(body) == pytest.approx(0.38, abs=0.005)
    assert shoulder_width(narrow) == pytest.approx(0.9 * shoulder_width(body))
    for joint, offset in body.joint_offsets.items():
        moved = narrow.joint_offsets[joint] - offset
        if joint.startswith('shoulder'):
            assert moved[0] == moved[2] == 0.0 and moved[1] != 0.0
        else:
            assert not moved.any(), joint
    assert narrow.shapes == body.shapes
    with pytest.raises(ValueError, match='positive'):
        with_shoulder_width(body, 0.0)


def test_the_upper_arms_lengthen_with_their_elbows_and_nothing_else_does():
    body = scaled_body(load_default_body(), 1.75)
    short = with_upper_arm_length(body, 0.9)
    assert upper_arm_length(short) == pytest.approx(0.9 * upper_arm_length(body))
    for part, shape in body.shapes.items():
        if part.startswith('upper_arm'):
            assert short.shapes[part].length == pytest.approx(0.9 * shape.length)
            assert (short.shapes[part].a, short.shapes[part].b) == (shape.a, shape.b)
        else:
            assert short.shapes[part] == shape, part
    for joint, offset in body.joint_offsets.items():
        moved = short.joint_offsets[joint] - offset
        assert moved.any() == joint.startswith('elbow'), joint
    # the elbow still sits at the upper arm's end
    assert short.joint_offsets['elbow_l'][2] == pytest.approx(short.shapes['upper_arm_l'].length)
    with pytest.raises(ValueError, match='positive'):
        with_upper_arm_length(body, float('nan'))


def test_the_size_is_the_least_of_a_parabola_through_the_misfits_and_only_a_clear_one():
    factors = np.array(FACTORS)
    u = factors - 1.0
    # a bowl with its least at 0.92: found between the tried sizes
    assert least_of_parabola(factors, 2.0 + 20.0 * (u + 0.08) ** 2, 0.02) == pytest.approx(0.92)
    # still falling at the largest: the largest
    assert least_of_parabola(factors, 2.0 - 3.0 * u, 0.02) == pytest.approx(1.12)
    # one frame's refits (the narrowest low by chance) in a curve bulging upwards: the template's
    assert least_of_parabola(factors, np.array([9.36, 9.90, 9.78, 9.61, 9.48]), 0.02) == 1.0
    # a least within the gain of the template's: the template's
    assert least_of_parabola(factors, 2.0 + 0.5 * (u - 0.06) ** 2, 0.02) == 1.0
    assert least_of_parabola(factors, np.full(5, 2.0), 0.02) == 1.0


def _track(template: Body, frames: int, proportion_frames: int) -> ArticulatedTracker:
    """Track the narrow-shouldered dancer's first frames (exact outlines) with ``template``."""
    scenario = make_scenario(
        'studio-dance', NARROW, 320, 240, frames, heading=np.radians(30.0), rig='ring4'
    )
    q, _ = scenario.coordinates(np.arange(frames) / scenario.frame_rate)
    settings = replace(TrackerSettings(), proportion_frames=proportion_frames)
    tracker = ArticulatedTracker(template, scenario.cameras, settings, initial_pose=q[0])
    for k, tables in enumerate(_contour_frames(scenario, NARROW, q, 'silhouettes')):
        assert tracker.step(int(k * 1e9 / scenario.frame_rate), tables).status == TRACKING
    return tracker


def test_a_template_too_wide_for_the_person_gets_the_persons_shoulders_after_its_frames():
    """The dancer's own body with the shoulders 12 % too far out: measured back in."""
    template = with_shoulder_width(NARROW, 1.12)
    tracker = _track(template, 14, 12)
    assert tracker.proportions is not None
    meter = tracker.proportions.done[0]
    assert meter.proportion.name == 'shoulder_width'
    assert meter.factor is not None and meter.measured == 4, meter
    assert meter.factor < 0.97, meter.sums
    assert shoulder_width(tracker.body) == pytest.approx(
        shoulder_width(NARROW), abs=0.06 * shoulder_width(NARROW)
    )
    # the pose it publishes puts the shoulders where the measured body has them
    rotations, origins = tracker.body.forward_kinematics(tracker.ekf.q)
    torso = rotations[0].T @ (origins[2] - origins[5])  # upper arms: left less right
    assert abs(torso[1]) == pytest.approx(shoulder_width(tracker.body), abs=1e-9)
    # the upper arms are measured next, on the body with the measured shoulders
    assert tracker.proportions.current is not None
    assert tracker.proportions.current.body is tracker.body
    # before its frames are over, and without them, the template's width stays
    early = _track(template, 6, 12)
    assert early.proportions.done == [] and early.body is template
    assert _track(template, 4, 0).proportions is None


def test_upper_arms_too_short_or_too_long_are_measured_to_the_persons_after_the_shoulders():
    """The silhouettes' disagreement tells the arms' length: the contour misfit took 0.88 of it.

    The dancer's own body with upper arms 12 % too short, or too long: the shoulders are kept
    (they are right), then the arms are measured to within a factor step of the dancer's.
    """
    truth = upper_arm_length(NARROW)
    for factor in (0.88, 1.12):
        tracker = _track(with_upper_arm_length(NARROW, factor), 25, 12)
        assert tracker.proportions is not None and tracker.proportions.finished
        shoulders, arms = tracker.proportions.done
        assert shoulders.factor == 1.0, shoulders.sums
        assert arms.proportion.name == 'upper_arm_length' and arms.measured == 4
        assert upper_arm_length(tracker.body) == pytest.approx(truth, abs=0.04 * truth), arms.sums
        assert shoulder_width(tracker.body) == shoulder_width(NARROW)
