"""Rohr §5.2.

The discrete linear Kalman filter over p = (X, X', Y, Y', Z, Z', pose, pose') (eq. 12-22).

Units: metres and gait cycles; time in images (the paper's Delta t = 1 image), so velocities are
per image.  Z (depth) and Y' are held: their process noise and initial variances are zero, so no
measurement moves them (§6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STATE = ('X', 'X_dot', 'Y', 'Y_dot', 'Z', 'Z_dot', 'pose', 'pose_dot')
MEASURED = (0, 2, 4, 6)  # eq. 21: X, Y, Z, pose


@dataclass(frozen=True)
class KalmanParams:
    """Rohr §6's values, in metres and cycles per image.

    25 images/s, 1.6 m and 1 cycle per second.
    """

    q_x_dot: float = 3.69e-4  # sigma^2_QX' = 3.69 cm^2/image^2
    q_y_dot: float = 0.0  # sigma^2_QY' = 0: Y' = 0
    q_pose_dot: float = 1.44e-4  # sigma^2_Qpose' = 0.000144 /image^2
    r_x: float = 0.04  # sigma^2_RX = 400 cm^2
    r_y: float = 0.01  # sigma^2_RY = 100 cm^2
    r_z: float = 0.04  # sigma^2_RZ (irrelevant: Z is held)
    r_pose: float = 0.04  # sigma^2_Rpose = 0.04


def transition(dt: float) -> np.ndarray:
    """Phi_{k,k-1} of eq. 19: constant velocities over ``dt`` images."""
    phi = np.eye(8)
    phi[[0, 2, 4, 6], [1, 3, 5, 7]] = dt
    return phi


def process_noise(params: KalmanParams, dt: float = 1.0) -> np.ndarray:
    """Q_k of eq. 20 (velocity noise only; Z' held), scaled by ``dt`` images."""
    return (
        np.diag([0.0, params.q_x_dot, 0.0, params.q_y_dot, 0.0, 0.0, 0.0, params.q_pose_dot]) * dt
    )


def measurement_matrix() -> np.ndarray:
    """H_k of eq. 21: X, Y, Z and pose are measured."""
    H = np.zeros((4, 8))
    H[np.arange(4), MEASURED] = 1.0
    return H


def measurement_noise(params: KalmanParams) -> np.ndarray:
    """R_k of eq. 22."""
    return np.diag([params.r_x, params.r_y, params.r_z, params.r_pose])


def initial_covariance(params: KalmanParams) -> np.ndarray:
    """P_0.

    The measurement variances for X, Y, pose ('the same uncertainties'), the process ones for their
    velocities, zero for the held Z, Z' and Y'.
    """
    return np.diag(
        [params.r_x, params.q_x_dot, params.r_y, 0.0, 0.0, 0.0, params.r_pose, params.q_pose_dot]
    )


class WalkingKalman:
    """Predict (eq. 14, 15) and update (eq. 16-18) of the walker's state."""

    def __init__(
        self, p0: np.ndarray, params: KalmanParams | None = None, P0: np.ndarray | None = None
    ) -> None:
        self.params = params or KalmanParams()
        self.p = np.asarray(p0, float).copy()
        self.P = initial_covariance(self.params) if P0 is None else np.asarray(P0, float).copy()
        self.H = measurement_matrix()
        self.R = measurement_noise(self.params)

    def predict(self, dt: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Predict p*_k = Phi p_{k-1} (eq. 14), P*_k = Phi P Phi^T + Q (eq. 15).

        The filter now holds them.
        """
        phi = transition(dt)
        self.p = phi @ self.p
        self.P = phi @ self.P @ phi.T + process_noise(self.params, dt)
        return self.p.copy(), self.P.copy()

    def update(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fold in the measurement z = (X, Y, Z, pose) (eq. 16-18)."""
        H, P = self.H, self.P
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + self.R)  # eq. 18
        self.p = self.p + K @ (np.asarray(z, float) - H @ self.p)  # eq. 16
        self.P = (np.eye(8) - K @ H) @ P  # eq. 17
        self.P = (self.P + self.P.T) / 2.0
        return self.p.copy(), self.P.copy()
