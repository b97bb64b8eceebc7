"""Extended Kalman filter over the articulated body (Kakadiaris & Metaxas §3, eq. 10-11).

Information form.

State: the generalized coordinates q and their tangent rates v (motion.py), with an error-state
covariance P (2n x 2n).  The update is an iterated EKF written in information form: each iteration
sums H^T W H and H^T W r over the measurements (cost linear in their number, n^2 each) and solves
one 2n x 2n system, so thousands of contour samples cost no more than a few hundred.  Measurements
are gated by their Mahalanobis distance against the predicted covariance, and the normalised
innovation squared (NIS) of the accepted ones tells whether the filter is consistent.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from memo_ros.core.multiview.motion import ConstantVelocity, retract


@dataclass
class Measurements:
    """Scalar measurements linearised at a pose.

    Jacobian rows H (m, n) over positions, residuals r, sigmas; optionally a robust scale per row
    (``robust``, in the units of r): the residual at which the row's weight is halved (Cauchy), inf
    for a row taken as it is.
    """

    H: np.ndarray
    r: np.ndarray
    sigma: np.ndarray
    robust: np.ndarray | None = None

    @classmethod
    def empty(cls, n: int) -> 'Measurements':
        """Return no measurement for an n-coordinate state (an update that changes nothing)."""
        return cls(np.zeros((0, n)), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return len(self.r)


@dataclass
class UpdateReport:
    """What an update did: measurements used and gated out, NIS, iterations."""

    used: int = 0
    gated: int = 0
    nis: float = float('nan')  # mean normalised innovation squared of the used measurements
    iterations: int = 0
    step: float = 0.0  # size of the last iteration's correction (max abs)


class ArticulatedEKF:
    """Iterated EKF over (q, v) with the shared constant-velocity model."""

    def __init__(self, model: ConstantVelocity) -> None:
        self.model = model
        self.n = model.n
        self.q = np.zeros(self.n)
        self.v = np.zeros(self.n)
        self.P = np.eye(2 * self.n)

    def initialize(
        self, q: np.ndarray, v: np.ndarray | None, sigma_q: np.ndarray, sigma_v: np.ndarray
    ) -> None:
        """Start from q (and v, zero if None) with diagonal standard deviations."""
        self.q = np.array(q, float)
        self.v = np.zeros(self.n) if v is None else np.array(v, float)
        self.P = np.diag(
            np.concatenate([np.broadcast_to(sigma_q, self.n), np.broadcast_to(sigma_v, self.n)])
            ** 2
        )

    def predict(self, dt: float) -> None:
        """x(t|t-1) = f(x), P(t|t-1) = F P F^T + Q (eq. 10)."""
        self.q, self.v = self.model.predict(self.q, self.v, dt)
        F = self.model.transition(dt)
        self.P = F @ self.P @ F.T + self.model.process_covariance(dt)

    def update(
        self,
        measure: Callable[[np.ndarray], Measurements],
        iterations: int = 3,
        gate: float = 4.0,
        tolerance: float = 1e-5,
    ) -> UpdateReport:
        """Run the iterated update (eq. 11).

        Relinearise ``measure`` at each iterate, gate, solve in information form.  Rows with a
        robust scale are reweighted at each iterate (iteratively reweighted least squares with
        Cauchy weights 1 / (1 + (r / scale)^2) on the residual r at that iterate): a measurement
        the pose cannot explain loses its pull instead of dragging the pose towards it.
        """
        n = self.n
        q0, v0, P0 = self.q, self.v, self.P
        info0 = np.linalg.inv(P0)
        Ppp = P0[:n, :n]
        delta = np.zeros(2 * n)
        report = UpdateReport()
        q = q0
        info = info0
        for it in range(iterations):
            m = measure(q)
            if not len(m):
                break
            # innovation covariance per measurement against the prediction: s = h P h^T + sigma^2
            s = np.einsum('ij,ij->i', m.H @ Ppp, m.H) + m.sigma**2
            # the residual the prior alone would leave: r + H (delta so far)
            innovation = m.r + m.H @ delta[:n]
            keep = innovation**2 <= gate**2 * s
            w = 1.0 / m.sigma**2
            if m.robust is not None:  # Cauchy weights on the residual at this iterate
                w = w / (1.0 + (m.r / m.robust) ** 2)
            if keep.all():  # the usual case: no copies of H
                H, used = m.H, innovation
            else:
                H, w, used = m.H[keep], w[keep], innovation[keep]
            H_scaled = H * np.sqrt(w)[:, None]  # H^T W H as one symmetric product
            info = info0.copy()
            info[:n, :n] += H_scaled.T @ H_scaled
            rhs = np.zeros(2 * n)
            rhs[:n] = H.T @ (w * used)
            new_delta = np.linalg.solve(info, rhs)
            step = float(np.max(np.abs(new_delta - delta)))
            delta = new_delta
            q = retract(q0, delta[:n], self.model.groups)
            report = UpdateReport(
                int(keep.sum()),
                int((~keep).sum()),
                float(np.mean(innovation[keep] ** 2 / s[keep])) if keep.any() else float('nan'),
                it + 1,
                step,
            )
            if step < tolerance:
                break
        if report.iterations:
            self.q = q
            self.v = v0 + delta[n:]
            self.P = np.linalg.inv(info)
            self.P = 0.5 * (self.P + self.P.T)
        return report
