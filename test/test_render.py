"""Ray-casting renderer against analytic projected areas and occlusion."""

import numpy as np
import pytest

from memo_ros.core.geometry.body import PART_NAMES, load_studio_actor
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import render, render_body
from memo_ros.core.geometry.rotations import rot_x

F = 500.0


def _camera(eye, target, up=(0.0, 0.0, 1.0), width=640, height=480, f=F):
    return Camera.look_at('cam', eye=eye, target=target, up=up, width=width, height=height, fx=f)


def _pose(origin, rotation=np.eye(3)):
    return np.asarray(rotation, float)[None], np.asarray(origin, float)[None]


def test_end_on_cylinder_projects_to_its_cap_ellipse():
    # camera on the cylinder's axis looking at its near cap from distance d
    a, b, length, d = 0.10, 0.05, 0.4, 2.0
    cam = _camera(eye=(0, 0, length + d), target=(0, 0, 0), up=(1, 0, 0))
    rotations, origins = _pose((0, 0, 0))
    r = render(cam, rotations, origins, np.array([[a, b]]), np.array([length]))
    expected = np.pi * (F * a / d) * (F * b / d)
    assert r.unoccluded_area[0] == pytest.approx(expected, rel=0.02)
    assert r.visible_area(1)[0] == r.unoccluded_area[0]
    assert np.nanmin(np.where(r.label > 0, r.depth, np.nan)) == pytest.approx(d, abs=1e-3)


def test_side_view_is_the_rectangle_between_the_tangent_planes():
    # a long-focal camera far away: nearly orthographic, width 2 f r / sqrt(D^2 - r^2)
    r_cyl, length, dist, f = 0.1, 1.0, 40.0, 10000.0
    cam = _camera(eye=(dist, 0, 0.5), target=(0, 0, 0.5), width=800, height=800, f=f)
    rotations, origins = _pose((0, 0, 0))
    r = render(cam, rotations, origins, np.array([[r_cyl, r_cyl]]), np.array([length]))
    width = 2 * f * r_cyl / np.sqrt(dist**2 - r_cyl**2)
    height = f * length / dist
    assert r.unoccluded_area[0] == pytest.approx(width * height, rel=0.02)


def test_occlusion_of_a_coaxial_cylinder_leaves_an_annulus():
    # a thin cylinder in front of a wide one, both on the optical axis
    d = 3.0
    cam = _camera(eye=(0, 0, d), target=(0, 0, 0), up=(1, 0, 0))
    rotations = np.stack([np.eye(3), np.eye(3)])
    origins = np.array(
        [[0, 0, 0.0], [0, 0, 1.0]]
    )  # back part 0: z in [0, 0.5]; front part 1: [1, 1.5]
    axes = np.array([[0.3, 0.3], [0.1, 0.1]])
    lengths = np.array([0.5, 0.5])
    r = render(cam, rotations, origins, axes, lengths)
    back_alone = np.pi * (F * 0.3 / (d - 0.5)) ** 2
    front = np.pi * (F * 0.1 / (d - 1.5)) ** 2
    assert r.unoccluded_area[0] == pytest.approx(back_alone, rel=0.02)
    assert r.visible_area(2)[0] == pytest.approx(back_alone - front, rel=0.03)
    assert r.visible_area(2)[1] == r.unoccluded_area[1]
    # the nearer part wins the depth test wherever both are hit
    assert np.all(r.depth[r.label == 2] < d - 0.5)


def test_reduced_resolution_scales_areas_with_the_square_of_the_scale():
    body = load_studio_actor()
    cam = _camera(eye=(3.5, 0, 1.0), target=(0, 0, 1.0))
    full = render_body(cam, body, body.neutral())
    quarter = render_body(cam, body, body.neutral(), scale=0.25)
    assert quarter.label.shape == (120, 160)
    big = full.unoccluded_area > 2000
    assert np.allclose(quarter.unoccluded_area[big] / full.unoccluded_area[big], 1 / 16, rtol=0.15)


def test_arm_behind_the_torso_is_hidden_from_the_side():
    body = load_studio_actor()
    side = _camera(eye=(0, 4.0, 1.0), target=(0, 0, 1.0))  # left side
    r = render_body(side, body, body.neutral())
    visible = r.visible_area(14)
    arm_r = [5, 6]  # upper_arm_r, forearm_r
    assert np.all(visible[arm_r] < 0.05 * r.unoccluded_area[arm_r])
    front = _camera(eye=(4.0, 0, 1.0), target=(0, 0, 1.0))
    rf = render_body(front, body, body.neutral())
    assert np.all(rf.visible_area(14)[arm_r] > 0.9 * rf.unoccluded_area[arm_r])


def test_normals_face_the_camera_and_parts_subset():
    body = load_studio_actor()
    cam = _camera(eye=(4.0, 0.5, 1.2), target=(0, 0, 1.0))
    r = render_body(cam, body, body.neutral(), normals=True)
    hit = r.label > 0
    # every visible surface normal faces its pixel's viewing ray
    rays_cam = cam.pixel_grid_rays(1.0) @ np.asarray(cam.R_world_cam)
    facing = np.sum(r.normal * rays_cam, axis=-1)[hit]
    assert np.all(facing < 1e-6) and np.median(facing) < -0.5
    rotations, origins = body.forward_kinematics(body.neutral())
    only_head = render(cam, rotations, origins, body.semi_axes, body.lengths, parts=[1])
    assert set(np.unique(only_head.label)) == {0, 2}
    tilted = render(
        cam, rot_x(0.3)[None] @ rotations[:1], origins[:1], body.semi_axes[:1], body.lengths[:1]
    )
    assert tilted.unoccluded_area[0] > 0


def test_a_rounded_part_is_a_capsule_reaching_past_its_joints():
    # side view, nearly orthographic: a capsule of radius r over [-r/2, L + r/2] is the
    # rectangle of its straight side (L - r long) plus two half-discs: the cylinder's area
    # plus (pi - 2) r^2
    r_cyl, length, dist, f = 0.1, 1.0, 40.0, 10000.0
    cam = _camera(eye=(dist, 0, 0.5), target=(0, 0, 0.5), width=800, height=800, f=f)
    rotations, origins = _pose((0, 0, 0))
    axes, lengths = np.array([[r_cyl, r_cyl]]), np.array([length])
    cylinder = render(cam, rotations, origins, axes, lengths)
    capsule = render(cam, rotations, origins, axes, lengths, shape='rounded', normals=True)
    extra = (np.pi - 2.0) * (f * r_cyl / dist) ** 2
    assert capsule.unoccluded_area[0] == pytest.approx(
        cylinder.unoccluded_area[0] + extra, rel=0.02
    )
    rows = np.nonzero(capsule.label.any(axis=1))[0]
    assert (rows[-1] - rows[0] + 1) * dist / f == pytest.approx(length + r_cyl, abs=0.01)
    n = capsule.normal[capsule.label > 0]
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert np.all(n[:, 2] < 0.0)  # every visible surface faces the camera (-z in its frame)


def test_a_rounded_limb_tapers_from_its_proximal_joint():
    # the body's thigh seen from the front: wider near the hip than near the knee, where the
    # tracker's cylinder has one width
    body = load_studio_actor()
    q = np.zeros(len(body.coordinate_names))
    rotations, origins = body.forward_kinematics(q)
    thigh = PART_NAMES.index('thigh_l')
    hip, knee = origins[thigh], origins[PART_NAMES.index('shank_l')]
    cam = _camera(eye=hip + (6.0, 0.0, -0.2), target=hip + (0.0, 0.0, -0.2), f=2000.0)
    only = np.array([thigh])
    widths = []
    for shape in ('cylinders', 'rounded'):
        label = render(
            cam, rotations, origins, body.semi_axes, body.lengths, parts=only, shape=shape
        ).label
        near, far = 0.8 * hip + 0.2 * knee, 0.2 * hip + 0.8 * knee
        rows = [int(cam.project(p[None])[0, 1]) for p in (near, far)]
        widths.append([int((label[v] > 0).sum()) for v in rows])
    (cyl_top, cyl_bottom), (top, bottom) = widths
    assert cyl_top == pytest.approx(cyl_bottom, abs=1)
    assert top > cyl_top * 1.05 and bottom < cyl_bottom * 0.95


def test_an_unknown_shape_is_refused():
    cam = _camera(eye=(3, 0, 0), target=(0, 0, 0))
    rotations, origins = _pose((0, 0, 0))
    with pytest.raises(ValueError, match='unknown shape'):
        render(cam, rotations, origins, np.array([[0.1, 0.1]]), np.array([1.0]), shape='mesh')
