"""A person's shoulder width, measured over the first tracked frames (shoulder_width.py)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from memo_ros.core.geometry.body import Body, load_default_body
from memo_ros.core.multiview.body_estimation import scaled_body
from memo_ros.core.multiview.shoulder_width import (
    SHOULDER_FACTORS,
    least_of_parabola,
    shoulder_width,
    with_shoulder_width,
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
        moved = narrow.joint_offsets[joint]
        if joint.startswith('shoulder'):
            assert moved[[0, 2]] == pytest.approx(offset[[0, 2]]) and moved[1] != offset[1]
        else:
            assert moved == pytest.approx(offset)
    assert np.array_equal(narrow.lengths, body.lengths)
    assert np.array_equal(narrow.semi_axes, body.semi_axes)
    with pytest.raises(ValueError):
        with_shoulder_width(body, 0.0)


def test_the_width_is_the_least_of_a_parabola_through_the_misfits_and_only_a_clear_one():
    factors = np.array(SHOULDER_FACTORS)
    u = factors - 1.0
    # a bowl with its least at 0.92: found between the tried widths
    assert least_of_parabola(factors, 2.0 + 20.0 * (u + 0.08) ** 2, 0.02) == pytest.approx(0.92)
    # still falling at the widest: the widest
    assert least_of_parabola(factors, 2.0 - 3.0 * u, 0.02) == pytest.approx(1.12)
    # one frame's refits (the narrowest low by chance) in a curve bulging upwards: the template's
    assert least_of_parabola(factors, np.array([9.36, 9.90, 9.78, 9.61, 9.48]), 0.02) == 1.0
    # a least within the gain of the template's: the template's
    assert least_of_parabola(factors, 2.0 + 0.5 * (u - 0.06) ** 2, 0.02) == 1.0
    assert least_of_parabola(factors, np.full(5, 2.0), 0.02) == 1.0


def _track(template: Body, frames: int, shoulder_frames: int) -> ArticulatedTracker:
    """Track the narrow-shouldered dancer's first frames (exact outlines) with ``template``."""
    scenario = make_scenario(
        'studio-dance', NARROW, 320, 240, frames, heading=np.radians(30.0), rig='ring4'
    )
    q, _ = scenario.coordinates(np.arange(frames) / scenario.frame_rate)
    settings = replace(TrackerSettings(), shoulder_frames=shoulder_frames)
    tracker = ArticulatedTracker(template, scenario.cameras, settings, initial_pose=q[0])
    for k, tables in enumerate(_contour_frames(scenario, NARROW, q, 'silhouettes')):
        assert tracker.step(int(k * 1e9 / scenario.frame_rate), tables).status == TRACKING
    return tracker


def test_a_template_too_wide_for_the_person_gets_the_persons_shoulders_after_its_frames():
    """The dancer's own body with the shoulders 12 % too far out: measured back in."""
    template = with_shoulder_width(NARROW, 1.12)
    tracker = _track(template, 13, 12)
    meter = tracker.shoulders
    assert meter is not None and meter.factor is not None and meter.measured == 4, meter
    assert meter.factor < 0.97, meter.sums
    assert shoulder_width(tracker.body) == pytest.approx(
        shoulder_width(NARROW), abs=0.06 * shoulder_width(NARROW)
    )
    # the pose it publishes puts the shoulders where the measured body has them
    rotations, origins = tracker.body.forward_kinematics(tracker.ekf.q)
    torso = rotations[0].T @ (origins[2] - origins[5])  # upper arms: left less right
    assert abs(torso[1]) == pytest.approx(shoulder_width(tracker.body), abs=1e-9)
    # before its frames are over, and without them, the template's width stays
    early = _track(template, 6, 12)
    assert early.shoulders.factor is None and early.body is template
    assert _track(template, 4, 0).shoulders is None
