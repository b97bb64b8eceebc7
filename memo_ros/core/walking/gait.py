"""Rohr's walking model (§3.2): joint-angle curves over one normalised gait cycle.

Medical gait data (here the CGM 2.3 normative curves, config/gait_cgm23_sagittal.csv,
standing in for Murray et al. 1964) are interpolated by periodic cubic splines,
so one parameter ``pose`` in [0, 1) fixes every joint.  The right side follows
the table (pose 0 = right heel strike), the left side lags half a cycle; the
vertical displacement of the body comes from the leg kinematics (the stance
leg's height).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from memo_ros.core.geometry.body import Body, lowest_point

ANGLES = ('pelvis_tilt', 'hip', 'knee', 'ankle', 'shoulder', 'elbow')


class GaitCurves:
    """Periodic cubic splines of the sagittal joint angles (radians) over the cycle fraction."""

    def __init__(self, table: str | Path | None = None, knots: int | None = None) -> None:
        """Load the CSV table; ``knots`` subsamples it to that many instants (Rohr used 10)."""
        if table is None:
            from memo_ros.paths import config_path

            table = config_path('gait_cgm23_sagittal.csv')
        data = np.genfromtxt(table, delimiter=',', names=True)
        phase = data['cycle_fraction']
        if phase[-1] >= 1.0 - 1e-9:  # the last sample repeats the first instant
            data, phase = data[:-1], phase[:-1]
        index = np.arange(len(phase))
        if knots is not None:
            if not 4 <= knots <= len(phase):
                raise ValueError(f'knots must be in [4, {len(phase)}]')
            index = np.round(np.linspace(0, len(phase), knots, endpoint=False)).astype(int)
        x = np.append(phase[index], 1.0)
        self.splines = {}
        for name in ANGLES:
            values = np.radians(data[f'{name}_deg'][index])
            self.splines[name] = CubicSpline(x, np.append(values, values[0]), bc_type='periodic')
        self.knots = x

    def angle(self, name: str, phase: np.ndarray | float, derivative: int = 0) -> np.ndarray:
        """Angle ``name`` (rad) or its derivative w.r.t. the cycle fraction at ``phase``.

        ``phase`` is wrapped into [0, 1).
        """
        return self.splines[name](np.mod(phase, 1.0), derivative)


class WalkingModel:
    """Generalized coordinates of a body walking with the gait curves: q(pose, x, y, heading)."""

    def __init__(self, body: Body, curves: GaitCurves | None = None, samples: int = 100) -> None:
        self.body = body
        self.curves = curves or GaitCurves()
        self._index = {name: body.coordinate_index(name) for name in body.coordinate_names}
        grid = np.linspace(0.0, 1.0, samples, endpoint=False)
        q = self.posture(grid)
        rotations, origins = body.forward_kinematics(q)
        height = -lowest_point(body, rotations, origins)
        # vertical displacement of the whole body (Rohr §3.2), periodic like the joints
        self._pelvis_height = CubicSpline(
            np.append(grid, 1.0), np.append(height, height[0]), bc_type='periodic'
        )

    def pelvis_height(self, pose: np.ndarray | float) -> np.ndarray:
        """Height of the pelvis centre above the ground at ``pose`` (stance leg on the ground)."""
        return self._pelvis_height(np.mod(pose, 1.0))

    def posture(self, pose: np.ndarray | float) -> np.ndarray:
        """Joint coordinates (..., n) at ``pose``, pelvis at the world origin, facing +x."""
        pose = np.asarray(pose, float)
        q = np.zeros(pose.shape + (self.body.n_coordinates,))
        c = self.curves
        for side, phase in (('r', pose), ('l', pose + 0.5)):
            # the torso stays upright: the thigh's angle to the vertical is hip flexion
            # measured against the forward-tilted pelvis, minus that tilt
            q[..., self._index[f'hip_{side}_y']] = c.angle('hip', phase) - c.angle(
                'pelvis_tilt', phase
            )
            q[..., self._index[f'knee_{side}_y']] = -c.angle('knee', phase)
            q[..., self._index[f'ankle_{side}_y']] = c.angle('ankle', phase)
            q[..., self._index[f'shoulder_{side}_y']] = c.angle('shoulder', phase)
            q[..., self._index[f'elbow_{side}_y']] = c.angle('elbow', phase)
        return q

    def coordinates(self, pose, x=0.0, y=0.0, heading=0.0) -> np.ndarray:
        """Full generalized coordinates.

        Walking posture at ``pose``, pelvis over (x, y), facing ``heading`` (rad).
        """
        pose = np.asarray(pose, float)
        q = self.posture(pose)
        q[..., 0] = x
        q[..., 1] = y
        q[..., 2] = self.pelvis_height(pose)
        q[..., 5] = heading
        return q
