"""Rotation helpers: numpy in, numpy out, vectorised over leading dimensions.

Conventions: rotation matrices act on column vectors (``v_world = R @ v_local``);
quaternions are in ROS order ``(x, y, z, w)``; rotation vectors are axis * angle
(radians).  scipy's Rotation is used internally where it is the robust choice.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

_SMALL_ANGLE = 1e-4  # below this |theta| the Rodrigues coefficients use their Taylor series


def _as_float(a) -> np.ndarray:
    return np.asarray(a, dtype=float)


def hat(v) -> np.ndarray:
    """Skew-symmetric matrix (..., 3, 3) of vectors (..., 3): the matrix of a times b is a x b."""
    v = _as_float(v)
    out = np.zeros(v.shape[:-1] + (3, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def rotvec_to_matrix(v) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from rotation vectors (..., 3) by Rodrigues' formula.

    Stable near 0.
    """
    v = _as_float(v)
    theta2 = np.sum(v * v, axis=-1)
    theta = np.sqrt(theta2)
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    # a = sin(t)/t, b = (1 - cos(t))/t^2, with Taylor series near t = 0
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0, np.sin(safe) / safe)
    b = np.where(
        small, 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, (1.0 - np.cos(safe)) / (safe * safe)
    )
    k = hat(v)
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def matrix_to_rotvec(R) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3), angle in [0, pi]."""
    R = _as_float(R)
    flat = R.reshape(-1, 3, 3)
    out = Rotation.from_matrix(flat).as_rotvec()
    return out.reshape(R.shape[:-2] + (3,))


def quat_to_matrix(q_xyzw) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in ROS order x, y, z, w.

    Normalised first.
    """
    q = _as_float(q_xyzw)
    norm = np.linalg.norm(q, axis=-1)
    if np.any(norm < 1e-12):
        raise ValueError('quaternion of zero length')
    q = q / norm[..., None]
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(R) -> np.ndarray:
    """Quaternions (..., 4) in ROS order x, y, z, w of rotation matrices (..., 3, 3).

    Sign chosen so w >= 0.
    """
    R = _as_float(R)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()  # scipy order is x, y, z, w too
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def axis_angle(axis, angle) -> np.ndarray:
    """Rotation matrices (..., 3, 3) by ``angle`` (...) rad about ``axis`` (..., 3).

    Which is normalised.
    """
    axis = _as_float(axis)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError('rotation axis of zero length')
    return rotvec_to_matrix(axis / norm * _as_float(angle)[..., None])


def _elementary(angle, i: int, j: int) -> np.ndarray:
    """Rotation (..., 3, 3) by ``angle`` in the (i, j) coordinate plane.

    Right-handed about the third axis.
    """
    angle = _as_float(angle)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    k = 3 - i - j
    out[..., k, k] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def rot_x(angle) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about x by ``angle`` (...) rad."""
    return _elementary(angle, 1, 2)


def rot_y(angle) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about y by ``angle`` (...) rad."""
    return _elementary(angle, 2, 0)


def rot_z(angle) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about z by ``angle`` (...) rad."""
    return _elementary(angle, 0, 1)
