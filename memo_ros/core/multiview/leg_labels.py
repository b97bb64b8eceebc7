"""Which leg is which: the legs exchanged in place.

A leg's silhouette does not say which leg it is.  A start from real silhouettes can put the
model's left leg where the person's right leg is and its right leg where his left one is, the hips
twisted to reach them, and fit the frame about as well as the right labelling: on the Pose2Sim
demo's first frames 27 of 88 starts at heights 1e-6 apart did.  :meth:`Anatomy.exchange` mirrors
each leg's angles onto the other, which moves the legs; :func:`legs_in_place` keeps the places and
exchanges the labels, so that the tracker can follow both labellings until the frames separate
them (the right one fitted better in 47 of the 48 frames of such a track).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.multiview.anatomy import JOINT_LIMITS

SIDES = ('l', 'r')
OTHER = {'l': 'r', 'r': 'l'}
# weight of a hip's and knee's change from the other leg's angles, per rad against metres of
# reach: a straight leg's knee and ankle do not fix the hip's twist, which this keeps
STAY_WEIGHT = 0.02
# two poses whose knees and ankles are all this near, leg by leg, label the legs alike (m)
SAME_PLACE_M = 0.05


def _leg_index(body: Body, side: str) -> np.ndarray:
    """Return the indices of a leg's hip (x, y, z) and knee coordinates."""
    names = body.coordinate_names
    return np.array(
        [names.index(f'hip_{side}_{a}') for a in 'xyz'] + [names.index(f'knee_{side}_y')]
    )


def leg_places(body: Body, q: np.ndarray) -> dict[str, np.ndarray]:
    """Return each leg's knee and ankle (the shank's and foot's origins), (2, 3) per side."""
    _, origins = body.forward_kinematics(q)
    return {
        side: origins[[PART_NAMES.index(f'shank_{side}'), PART_NAMES.index(f'foot_{side}')]]
        for side in SIDES
    }


def legs_in_place(body: Body, q: np.ndarray) -> np.ndarray:
    """Return ``q`` with each leg's knee and ankle moved to where the other leg's are.

    Each hip and knee is solved so that its knee and ankle reach the other leg's, starting from
    the other leg's angles; each ankle takes the other's hinge angle.  The torso, arms and head
    stay, and the knees stay within their anatomical range.
    """
    q = np.asarray(q, float)
    names = body.coordinate_names
    places = leg_places(body, q)
    legs = {side: _leg_index(body, side) for side in SIDES}
    ankles = {side: names.index(f'ankle_{side}_y') for side in SIDES}
    out = q.copy()
    for side in SIDES:
        out[legs[side]] = q[legs[OTHER[side]]]
        out[ankles[side]] = q[ankles[OTHER[side]]]
    for side in SIDES:
        index, target = legs[side], places[OTHER[side]]
        parts = [PART_NAMES.index(f'shank_{side}'), PART_NAMES.index(f'foot_{side}')]
        start = out[index].copy()
        low, high = JOINT_LIMITS[f'knee_{side}_y']
        lower = np.array([-np.inf, -np.inf, -np.inf, low])
        upper = np.array([np.inf, np.inf, np.inf, high])

        def residual(x: np.ndarray, index=index, parts=parts, target=target, start=start):
            trial = out.copy()
            trial[index] = x
            reached = body.forward_kinematics(trial)[1][parts]
            return np.concatenate([(reached - target).ravel(), STAY_WEIGHT * (x - start)])

        inside = np.clip(start, lower + 1e-6, upper - 1e-6)
        out[index] = least_squares(residual, inside, bounds=(lower, upper)).x
    return out


def legs_alike(body: Body, q: np.ndarray, other: np.ndarray) -> bool:
    """Return whether two poses put each leg's knee and ankle in the same places."""
    a, b = leg_places(body, q), leg_places(body, other)
    return all(np.linalg.norm(a[s] - b[s], axis=1).max() < SAME_PLACE_M for s in SIDES)
