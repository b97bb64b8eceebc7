"""Forward kinematics, joint conventions and surface nodes of the body model."""

import numpy as np
import pytest

from memo_ros.core.geometry.body import (
    JOINT_NAMES,
    PART_NAMES,
    Body,
    load_default_body,
    load_studio_actor,
)
from memo_ros.core.geometry.rotations import rotvec_to_matrix
from memo_ros.core.geometry.surface import body_surface, normal_variation


@pytest.fixture(scope='module')
def body():
    return load_default_body()


def test_names_follow_the_design(body):
    assert len(PART_NAMES) == 14 and len(JOINT_NAMES) == 13
    assert body.coordinate_names[:6] == (
        'root_tx',
        'root_ty',
        'root_tz',
        'root_rx',
        'root_ry',
        'root_rz',
    )
    for name in body.coordinate_names[6:]:
        joint, axis = name.rsplit('_', 1)
        assert joint in JOINT_NAMES and axis in 'xyz'


def test_the_template_has_anatomical_shoulders_and_the_studio_actor_broad_ones(body):
    """A real person is measured with the template: its shoulder joints near anatomy's 350 mm.

    The simulated studios' actor is the same adult with its hanging arms clear of the chest.
    """

    def shoulder_width(b: Body) -> float:
        _, origins = b.forward_kinematics(b.neutral())
        left, right = (origins[PART_NAMES.index(p)] for p in ('upper_arm_l', 'upper_arm_r'))
        return float(np.linalg.norm(left - right))

    actor = load_studio_actor()
    assert shoulder_width(body) == pytest.approx(0.38, abs=0.005)
    assert shoulder_width(actor) == pytest.approx(0.42, abs=0.005)
    assert actor.shapes == body.shapes
    same = [j for j in JOINT_NAMES if not j.startswith('shoulder')]
    assert all(np.allclose(actor.joint_offsets[j], body.joint_offsets[j]) for j in same)


def test_neutral_pose_stands_on_the_ground_at_the_shipped_height(body):
    rotations, origins = body.forward_kinematics(body.neutral())
    assert body.standing_height() == pytest.approx(1.75, abs=0.01)
    ends = body.distal_ends(rotations, origins)
    # hanging limbs point down, head and torso up, feet forward
    for part in ('upper_arm_l', 'forearm_r', 'thigh_l', 'shank_r'):
        assert rotations[PART_NAMES.index(part)][:, 2] == pytest.approx([0, 0, -1])
    for part in ('torso', 'head'):
        assert rotations[PART_NAMES.index(part)][:, 2] == pytest.approx([0, 0, 1])
    assert rotations[PART_NAMES.index('foot_l')][:, 2] == pytest.approx([1, 0, 0])
    # left parts on +y (REP 103: the body faces +x)
    assert (
        origins[PART_NAMES.index('upper_arm_l'), 1]
        > 0
        > origins[PART_NAMES.index('upper_arm_r'), 1]
    )
    assert ends[PART_NAMES.index('head'), 2] == pytest.approx(body.standing_height())


def test_children_start_where_parents_end(body):
    rng = np.random.default_rng(1)
    q = body.neutral() + rng.normal(0, 0.4, body.n_coordinates)
    rotations, origins = body.forward_kinematics(q)
    ends = body.distal_ends(rotations, origins)
    for j in body.joints:
        if body.joint_offsets[j.name][:2].any():  # shoulders and hips sit beside the torso axis
            continue
        assert np.allclose(origins[j.child], ends[j.parent], atol=1e-12), j.name


def test_root_moves_and_turns_the_whole_body_rigidly(body):
    q = body.neutral()
    q[body.coordinate_index('elbow_l_y')] = 0.7
    r0, o0 = body.forward_kinematics(q)
    q2 = q.copy()
    q2[:3] += [0.3, -0.2, 0.1]
    q2[3:6] = [0.1, -0.2, 0.9]
    r1, o1 = body.forward_kinematics(q2)
    R = rotvec_to_matrix(q2[3:6])
    expected = (o0 - q[:3]) @ R.T + q2[:3]
    assert np.allclose(o1, expected)
    assert np.allclose(r1, R @ r0)


def test_joint_sign_conventions(body):
    def tip(name, value, part):
        q = body.neutral()
        q[body.coordinate_index(name)] = value
        r, o = body.forward_kinematics(q)
        return body.distal_ends(r, o)[PART_NAMES.index(part)] - o[PART_NAMES.index(part)]

    assert tip('shoulder_r_y', 0.5, 'upper_arm_r')[0] > 0.1  # flexion swings the arm forward
    assert tip('hip_l_y', 0.5, 'thigh_l')[0] > 0.1  # hip flexion: thigh forward
    assert tip('ankle_l_y', 0.3, 'foot_l')[2] > 0.05  # dorsiflexion raises the toes
    q = body.neutral()
    q[body.coordinate_index('knee_l_y')] = -0.8  # knee flexion is negative
    r, o = body.forward_kinematics(q)
    shank = PART_NAMES.index('shank_l')
    assert (body.distal_ends(r, o)[shank] - o[shank])[0] < -0.1


def test_batched_kinematics_equal_single(body):
    rng = np.random.default_rng(2)
    qs = body.neutral() + rng.normal(0, 0.3, (5, 3, body.n_coordinates))
    r, o = body.forward_kinematics(qs)
    r1, o1 = body.forward_kinematics(qs[3, 2])
    assert r.shape == (5, 3, 14, 3, 3) and np.allclose(r[3, 2], r1) and np.allclose(o[3, 2], o1)
    assert np.allclose(np.einsum('...ji,...jk->...ik', r, r), np.eye(3), atol=1e-12)


def test_body_yaml_round_trip_and_errors(body, tmp_path):
    again = Body.from_dict(body.to_dict())
    assert np.allclose(again.lengths, body.lengths) and np.allclose(
        again.semi_axes, body.semi_axes
    )
    data = body.to_dict()
    del data['parts']['head']
    with pytest.raises(ValueError, match='head'):
        Body.from_dict(data)
    data = body.to_dict()
    data['parts']['torso']['length'] = -1
    with pytest.raises(ValueError, match='positive'):
        Body.from_dict(data)


def test_surface_nodes_lie_on_the_cylinders_with_outward_normals(body):
    nodes = body_surface(body)
    a, b = body.semi_axes[nodes.part].T
    length = body.lengths[nodes.part]
    x, y, z = nodes.points.T
    side = np.abs(nodes.normals[:, 2]) < 1e-9
    assert np.allclose((x[side] / a[side]) ** 2 + (y[side] / b[side]) ** 2, 1.0)
    assert np.all((z >= -1e-12) & (z <= length + 1e-12))
    assert np.allclose(np.linalg.norm(nodes.normals, axis=1), 1.0)
    # outward: the normal points away from the axis on the side, away from the middle on the caps
    assert np.all(np.sum(nodes.normals[side, :2] * nodes.points[side, :2], axis=1) > 0)
    caps = ~side
    assert np.all(np.sign(nodes.normals[caps, 2]) == np.sign(z[caps] - length[caps] / 2))
    eps = normal_variation(nodes)
    assert eps.shape == (14,) and np.all((eps > 0.0) & (eps < 1.0))
    # a finer tessellation varies less between neighbours (eq. 12)
    assert np.all(normal_variation(body_surface(body, n_around=48, n_along=16)) >= eps - 1e-9)
