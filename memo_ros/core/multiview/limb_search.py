"""Finding a limb again: each limb tried in a few canonical postures, the rest kept.

The filter follows a limb only from where it was.  Started from a pose whose limbs are not where
the person's are (a tracker restarted while an arm is raised; a studio ``initial_pose`` that is
not the first frame's), a limb settles where another part's contour holds it, and the forces, all
local, cannot take it out.  Like the heading search at a start, this search tries each limb in a
small set of postures with the rest of the body where it is: the upper limb along a few directions
of the torso's frame, its hinge at three flexions, the upper arm at three twists.  A posture is
scored cheaply, as a truncated chamfer: how far each contour sample lies from the nearest outline
node of the body with the limb so posed, plus how far the limb's outline lies outside each
camera's silhouette.  The filter's own update then refines the most promising, and the tracker
keeps one only when the full misfit says it fits better (``ArticulatedTracker._search_limbs``).
A pair of limbs is posed together (:func:`pair_postures`) when the search again for a lost limb
finds nothing better alone (``ArticulatedTracker._search_pairs``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.rotations import matrix_to_rotvec, rot_z, rotvec_to_matrix
from memo_ros.core.multiview.correspondence import rig_outline_candidates
from memo_ros.core.multiview.model_nodes import ModelNodes
from memo_ros.core.multiview.silhouette_hold import SilhouetteField

_H = np.sqrt(0.5)
# the upper arm's directions in the torso's frame (x forward, y to the arm's own side, z up):
# hanging, forward, sideways, overhead, the four diagonals between them, half back, across the
# chest, forward and out
ARM_DIRECTIONS = np.array(
    [
        (0, 0, -1),
        (1, 0, 0),
        (0, 1, 0),
        (0, 0, 1),
        (_H, 0, -_H),
        (_H, 0, _H),
        (0, _H, -_H),
        (0, _H, _H),
        (-_H, 0, -_H),
        (_H, -_H, 0),
        (_H, _H, 0),
    ]
)
ELBOW_FLEXIONS = (0.0, 1.2, 2.2)  # rad (JOINT_LIMITS: 0 to 2.6)
ARM_TWISTS = (0.0, np.pi / 2, -np.pi / 2)  # the upper arm about its own axis, when the elbow bends
# the thigh's: standing, kicked forwards by 45 and 90 degrees, out to the side, back
LEG_DIRECTIONS = np.array(
    [(0, 0, -1), (_H, 0, -_H), (1, 0, 0), (0, 0.5, -np.sqrt(0.75)), (-0.5, 0, -np.sqrt(0.75))]
)
KNEE_FLEXIONS = (0.0, -1.2, -2.2)  # rad (JOINT_LIMITS: -2.6 to 0)
LIMBS = {  # limb: (ball joint, hinge, coordinates set to zero in a posture, parts)
    f'{kind}_{side}': (
        f'{ball}_{side}',
        f'{hinge}_{side}_y',
        tuple(f'{joint}_{side}_{axis}' for joint, axis in zeros),
        tuple(f'{p}_{side}' for p in parts),
    )
    for side in ('l', 'r')
    for kind, ball, hinge, zeros, parts in (
        (
            'arm',
            'shoulder',
            'elbow',
            (('elbow', 'z'), ('wrist', 'y'), ('wrist', 'x')),
            ('upper_arm', 'forearm', 'hand'),
        ),
        ('leg', 'hip', 'knee', (('ankle', 'y'),), ('thigh', 'shank', 'foot')),
    )
}
TRUNCATION_PX = 25.0  # a sample's or an outline point's distance counts up to this much
OUTSIDE_POINTS = 5  # points along each outline line looked up in the silhouette's distance map
# each limb's best postures combined with the other's when a pair is searched together: a limb's
# own score ranks its posture low while the other limb, lost, covers its outline
PAIR_TOP = 6


@dataclass(frozen=True)
class LimbPostures:
    """One limb's canonical postures: the coordinates they set and their values."""

    limb: str
    index: np.ndarray  # (m,) coordinate indices
    values: np.ndarray  # (K, m)
    parts: np.ndarray  # (3,) part indices of the limb

    def apply(self, q: np.ndarray) -> np.ndarray:
        """Return ``q`` (n,) in every posture (K, n)."""
        out = np.repeat(np.asarray(q, float)[None], len(self.values), axis=0)
        out[:, self.index] = self.values
        return out


def limb_postures(body: Body) -> list[LimbPostures]:
    """Return the canonical postures of the four limbs (arms first)."""
    names = body.coordinate_names
    joints = {j.name: j for j in body.joints}
    out = []
    for limb, (ball, hinge, zeros, parts) in LIMBS.items():
        side = 1.0 if limb.endswith('_l') else -1.0
        arm = limb.startswith('arm')
        directions = (ARM_DIRECTIONS if arm else LEG_DIRECTIONS) * np.array([1.0, side, 1.0])
        flexions = ELBOW_FLEXIONS if arm else KNEE_FLEXIONS
        twists = ARM_TWISTS if arm else (0.0,)
        rest = joints[ball].rest
        rows = []
        for d in directions:
            aligned = rotvec_to_matrix(_rotation_between(np.array([0.0, 0.0, 1.0]), rest.T @ d))
            for flexion in flexions:
                for twist in twists if flexion else (0.0,):
                    rows.append(
                        [*matrix_to_rotvec(aligned @ rot_z(twist)), flexion] + [0.0] * len(zeros)
                    )
        start = names.index(f'{ball}_x')
        index = [start, start + 1, start + 2, names.index(hinge)]
        index += [names.index(z) for z in zeros]
        out.append(
            LimbPostures(
                limb,
                np.array(index),
                np.array(rows),
                np.array([PART_NAMES.index(p) for p in parts]),
            )
        )
    return out


def pair_postures(
    a: LimbPostures, b: LimbPostures, q: np.ndarray, a_scores: np.ndarray, b_scores: np.ndarray
) -> np.ndarray:
    """Return ``q`` (n,) with a pair of limbs posed together, (PAIR_TOP^2, n).

    Every combination of each limb's PAIR_TOP best postures on its own cheap score
    (``a_scores``, ``b_scores``: :func:`posture_scores` of ``q`` and then each posture).
    """
    top_a = np.argsort(a_scores[1:])[:PAIR_TOP]
    top_b = np.argsort(b_scores[1:])[:PAIR_TOP]
    out = np.repeat(np.asarray(q, float)[None], len(top_a) * len(top_b), axis=0)
    out[:, a.index] = np.repeat(a.values[top_a], len(top_b), axis=0)
    out[:, b.index] = np.tile(b.values[top_b], (len(top_a), 1))
    return out


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the shortest rotation vector turning unit ``a`` onto unit ``b``."""
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(np.dot(a, b))
    if s < 1e-9:
        return np.zeros(3) if c > 0 else np.array([np.pi, 0.0, 0.0])
    return axis / s * np.arctan2(s, c)


def posture_scores(
    body: Body,
    nodes: ModelNodes,
    cameras: list[Camera],
    samples: list[np.ndarray],
    fields: list[SilhouetteField | None],
    poses: np.ndarray,
    parts: np.ndarray,
    truncation_px: float = TRUNCATION_PX,
) -> np.ndarray:
    """Return a cheap misfit (px^2) of each of the poses (K, n) that differ only in one limb.

    The body outside the limb's ``parts`` must be the same in every pose (``poses[0]``'s outline
    nodes stand for it).  Each limb part's outline in an image is taken as the two lines at its
    projected radius either side of its projected axis.  Per camera, each sample (``samples``,
    (N, 2) pixels) counts its squared distance to the nearest outline, and the limb's outline
    lines their squared distance outside the camera's silhouette (``fields``; None: not counted),
    each up to ``truncation_px``.
    """
    rotations, origins = body.forward_kinematics(poses)
    limb = np.isin(np.arange(len(PART_NAMES)), parts)
    t2 = truncation_px**2
    ends = np.stack(  # (K, L, 2, 3): each limb part's axis from its origin along its z
        [
            origins[:, parts],
            origins[:, parts] + rotations[:, parts][..., 2] * body.lengths[parts, None],
        ],
        axis=2,
    )
    radius = body.semi_axes[parts].mean(axis=1)  # (L,)
    along = np.linspace(0.0, 1.0, OUTSIDE_POINTS)
    rest = rig_outline_candidates(cameras, nodes, rotations[0], origins[0])
    scores = np.zeros(len(poses))
    for camera, uv, cand, field in zip(cameras, samples, rest, fields):
        uv = np.asarray(uv, float).reshape(-1, 2)
        keep = ~limb[cand.part] & np.all(np.isfinite(cand.uv), axis=1)
        rest_d2 = np.full(len(uv), t2)
        if len(uv) and keep.any():  # the rest of the body's nearest outline node, once
            d, _ = cKDTree(cand.uv[keep]).query(uv, distance_upper_bound=truncation_px)
            rest_d2 = np.minimum(d, truncation_px) ** 2
        with np.errstate(all='ignore'):
            a, b = _project(camera, ends)  # (K, L, 2) pixels of the axis' two ends
            depth = camera.world_to_camera(ends.reshape(-1, 3))[:, 2].reshape(ends.shape[:3])
            r = camera.K[0, 0] * radius / depth.mean(axis=2)  # (K, L) px
            r = np.where(depth.min(axis=2) > 0, r, np.nan)  # a part behind the camera: no outline
            if len(uv):
                d = np.abs(_segment_distance(uv, a, b) - r[..., None])  # (K, L, N)
                d = np.where(np.isfinite(d), d, truncation_px).min(axis=1)
                scores += np.minimum(rest_d2, np.minimum(d, truncation_px) ** 2).sum(axis=1)
            if field is not None:
                axis = b - a
                normal = np.stack([-axis[..., 1], axis[..., 0]], -1)
                normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
                on_axis = a[..., None, :] + along[:, None] * axis[..., None, :]  # (K, L, T, 2)
                offset = (r[..., None] * normal)[..., None, :]  # (K, L, 1, 2)
                lines = np.stack([on_axis + offset, on_axis - offset], axis=2)  # (K, L, 2, T, 2)
                held, distance, _ = field.lookup(lines.reshape(-1, 2))
                outside = np.where(held, np.minimum(distance, truncation_px) ** 2, 0.0)
                scores += outside.reshape(len(poses), -1).sum(axis=1)
    return scores


def _project(camera: Camera, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the pixels (K, L, 2) of the two ends (K, L, 2, 3) of every limb part's axis."""
    uv = camera.project(ends.reshape(-1, 3)).reshape(ends.shape[:3] + (2,))
    return uv[:, :, 0], uv[:, :, 1]


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the distance (..., N) of each point (N, 2) to each segment a-b (..., 2).

    x and y kept apart: a sum over a last axis of two is numpy's slowest way to add two numbers.
    """
    ab = b - a
    abx, aby = ab[..., 0, None], ab[..., 1, None]  # (..., 1)
    length2 = np.maximum(abx * abx + aby * aby, 1e-12)
    apx = points[:, 0] - a[..., 0, None]  # (..., N)
    apy = points[:, 1] - a[..., 1, None]
    t = np.clip((apx * abx + apy * aby) / length2, 0.0, 1.0)
    cx, cy = apx - t * abx, apy - t * aby
    return np.sqrt(cx * cx + cy * cy)
