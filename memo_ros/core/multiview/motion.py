"""The motion model shared by the selector and the tracker.

Constant velocity per degree of freedom.

The filter's state is the generalized coordinates ``q`` (DESIGN.md names) and their velocities.
Rotations kept as rotation vectors (the floating base and the ball joints) are moved by local
increments, ``R <- R exp(delta)``, so nothing gimbal-locks and the error state is additive
(Kakadiaris & Metaxas use quaternions for the same reason).  Velocities inside the filter are
tangent rates (body angular velocity for those groups); ``/memo/joint_states`` carries the
coordinates' own time derivatives, and :func:`coordinate_rates` / :func:`tangent_rates` convert
exactly between the two, so the selector predicts frame t from the published posterior exactly as
the tracker does.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from memo_ros.core.geometry.body import Body
from memo_ros.core.geometry.rotations import hat, matrix_to_rotvec, rotvec_to_matrix

EXTRA_STATE_NAMES = ('gait_phase',)  # JointState entries that are not body coordinates


def rotation_groups(body: Body) -> np.ndarray:
    """Return indices (G, 3) of the rotation-vector triples in ``q``.

    The root's and every ball joint's.
    """
    starts = [body.coordinate_index('root_rx')]
    starts += [body.coordinate_index(f'{j.name}_x') for j in body.joints if j.axes == 'ball']
    return np.array(starts, int)[:, None] + np.arange(3)


def right_jacobian(r: np.ndarray) -> np.ndarray:
    """SO(3) right Jacobian (..., 3, 3): exp(r + dr) = exp(r) exp(J_r(r) dr) to first order."""
    r = np.asarray(r, float)
    t2 = np.sum(r * r, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    safe = np.where(small, 1.0, t)
    a = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0, (safe - np.sin(safe)) / safe**3)
    k = hat(r)
    return np.eye(3) - a[..., None, None] * k + b[..., None, None] * (k @ k)


def retract(q: np.ndarray, delta: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Q (+) delta.

    Additive for scalar coordinates, R(r) exp(delta) for rotation groups; batched over rows.

    The rotations are composed as unit quaternions (the same rotation as the matrix product,
    without converting matrices back to rotation vectors, the slow part at the tracker's few
    groups).
    """
    q, delta = np.asarray(q, float), np.asarray(delta, float)
    out = q + delta
    r, d = q[..., groups], delta[..., groups]
    composed = Rotation.from_rotvec(r.reshape(-1, 3)) * Rotation.from_rotvec(d.reshape(-1, 3))
    out[..., groups] = composed.as_rotvec().reshape(r.shape)
    return out


def local_difference(q_to: np.ndarray, q_from: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Return the increment delta with q_from (+) delta = q_to (inverse of :func:`retract`)."""
    q_to, q_from = np.asarray(q_to, float), np.asarray(q_from, float)
    out = q_to - q_from
    r_to, r_from = rotvec_to_matrix(q_to[..., groups]), rotvec_to_matrix(q_from[..., groups])
    out[..., groups] = matrix_to_rotvec(np.swapaxes(r_from, -1, -2) @ r_to)
    return out


def coordinate_rates(q: np.ndarray, v: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Time derivatives of the coordinates from tangent rates: r' = J_r(r)^-1 omega."""
    out = np.array(v, float)
    jr = right_jacobian(np.asarray(q, float)[..., groups])
    out[..., groups] = np.linalg.solve(jr, out[..., groups][..., None])[..., 0]
    return out


def tangent_rates(q: np.ndarray, qdot: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Tangent rates from the coordinates' time derivatives: omega = J_r(r) r'."""
    out = np.array(qdot, float)
    jr = right_jacobian(np.asarray(q, float)[..., groups])
    out[..., groups] = (jr @ out[..., groups][..., None])[..., 0]
    return out


@dataclass
class ProcessNoise:
    """White-noise acceleration densities per kind of degree of freedom, continuous, per second."""

    root_translation: float = 2.0  # m/s^2 /sqrt(Hz)
    root_rotation: float = 3.0  # rad/s^2 /sqrt(Hz)
    joint_rotation: float = 6.0  # rad/s^2 /sqrt(Hz); larger lets weakly observed joints drift

    def densities(self, body: Body) -> np.ndarray:
        """Sigma per coordinate (n,)."""
        sigma = np.full(body.n_coordinates, self.joint_rotation)
        sigma[0:3] = self.root_translation
        sigma[3:6] = self.root_rotation
        return sigma


class ConstantVelocity:
    """Constant velocity per degree of freedom with white-noise acceleration.

    The tracker's and selector's model.
    """

    def __init__(self, body: Body, noise: ProcessNoise | None = None) -> None:
        self.body = body
        self.n = body.n_coordinates
        self.groups = rotation_groups(body)
        self.noise = noise or ProcessNoise()
        self._sigma = self.noise.densities(body)

    def predict(self, q: np.ndarray, v: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Mean prediction: q (+) v dt, v unchanged (tangent rates)."""
        return retract(q, np.asarray(v, float) * dt, self.groups), np.array(v, float)

    def predict_coordinates(
        self, q: np.ndarray, qdot: np.ndarray, dt: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Prediction from published coordinates and their time derivatives.

        What the selector receives.
        """
        v = tangent_rates(q, qdot, self.groups)
        q_next, v_next = self.predict(q, v, dt)
        return q_next, coordinate_rates(q_next, v_next, self.groups)

    def transition(self, dt: float) -> np.ndarray:
        """Error-state transition F (2n, 2n): delta_q' = delta_q + dt delta_v, first order."""
        f = np.eye(2 * self.n)
        f[: self.n, self.n :] = dt * np.eye(self.n)
        return f

    def process_covariance(self, dt: float) -> np.ndarray:
        """Q (2n, 2n) of white-noise acceleration integrated over dt, per degree of freedom."""
        s2 = self._sigma**2
        q = np.zeros((2 * self.n, 2 * self.n))
        i = np.arange(self.n)
        q[i, i] = s2 * dt**3 / 3.0
        q[i, i + self.n] = q[i + self.n, i] = s2 * dt**2 / 2.0
        q[i + self.n, i + self.n] = s2 * dt
        return q


def named_values_problem(names: Sequence[str], values: Sequence[float] | np.ndarray) -> str | None:
    """Return why (name, value) pairs do not give each named coordinate one value, or None."""
    if not names:
        return 'no names (an empty message)'
    if len(values) != len(names):
        return f'{len(names)} names but {len(values)} positions'
    twice = sorted(n for n, count in Counter(names).items() if count > 1)
    if twice:
        return f'named more than once: {", ".join(twice[:5])}'
    return None


def coordinates_from_names(
    body: Body, names, values, default: np.ndarray | None = None
) -> np.ndarray:
    """Return a coordinate vector from (name, value) pairs.

    Unnamed ones from ``default`` (neutral); unknown names raise KeyError.
    """
    q = np.array(default if default is not None else body.neutral(), float)
    index = {n: i for i, n in enumerate(body.coordinate_names)}
    for name, value in zip(names, values):
        if name in EXTRA_STATE_NAMES:
            continue
        if name not in index:
            raise KeyError(f'unknown coordinate {name!r}')
        q[index[name]] = value
    return q
