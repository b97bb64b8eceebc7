"""Calibrated pinhole camera with lens distortion (Kakadiaris & Metaxas §2.1.1, eq. 5-9).

Frames (REP 103, DESIGN.md): ``R_world_cam`` is the orientation of the
camera's optical frame (z forward, x right, y down) in ``world`` and
``t_world_cam`` its optical centre, so a world point is
``P = t_world_cam + R_world_cam @ Pc`` (eq. 5).

Intrinsics follow OpenCV and sensor_msgs/CameraInfo:
``K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]`` and ``D`` in the order
``k1, k2, p1, p2, k3`` ('plumb_bob') or ``k1, k2, p1, p2, k3, k4, k5, k6``
('rational_polynomial'); pixel (0, 0) is the centre of the top-left pixel.
With ``x = Xc/Zc``, ``y = Yc/Zc`` and ``r2 = x^2 + y^2``::

    radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
    u = fx xd + skew yd + cx,  v = fy yd + cy

Without distortion this is the paper's eq. 6 with f in pixels; its image
Jacobian H (eq. 8) extended by the distortion and intrinsics is
:meth:`Camera.projection_jacobian_camera`, and chained with the inverse camera
rotation (eq. 9) :meth:`Camera.project_with_jacobian`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, overload

import cv2
import numpy as np

from memo_ros.core.geometry.rotations import matrix_to_quat, quat_to_matrix

MIN_DEPTH = 1e-9  # metres; points with optical z <= this are behind the camera and project to NaN
N_COEFFS = {'plumb_bob': 5, 'rational_polynomial': 8, 'none': 0}
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


def perspective_jacobian(Pc: np.ndarray, f: float = 1.0) -> np.ndarray:
    """Return the paper's H (eq. 8).

    d(f x/z, f y/z)/d(x, y, z) for camera-frame points (..., 3) -> (..., 2, 3).
    """
    Pc = np.asarray(Pc, float)
    x, y, z = Pc[..., 0], Pc[..., 1], Pc[..., 2]
    zero = np.zeros_like(z)
    with np.errstate(divide='ignore', invalid='ignore'):
        inv_z = np.where(z > MIN_DEPTH, 1.0 / z, np.nan)
    return f * np.stack(
        [
            np.stack([inv_z, zero, -x * inv_z * inv_z], -1),
            np.stack([zero, inv_z, -y * inv_z * inv_z], -1),
        ],
        -2,
    )


def is_camera_matrix(K: np.ndarray) -> bool:
    """Return whether a 3x3 K is [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0."""
    return not (K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or np.any(K[2] != (0.0, 0.0, 1.0)))


def _normalise_model(model: str | None, D: np.ndarray) -> tuple[str, np.ndarray]:
    """Canonical distortion model name and D zero-padded to its length."""
    model = (model or '').strip().lower()
    if model in ('', 'none'):
        if not np.any(D):
            return 'none', np.zeros(0)
        if model == 'none':
            raise ValueError(f"distortion_model 'none' with non-zero D {D.tolist()}")
        model = 'plumb_bob' if len(D) <= 5 else 'rational_polynomial'
    if model not in N_COEFFS:
        raise ValueError(
            f"unsupported distortion_model {model!r} (use 'plumb_bob', 'rational_polynomial' or "
            "'none')"
        )
    n = N_COEFFS[model]
    if len(D) > n:
        raise ValueError(f'{model} takes at most {n} distortion coefficients, got {len(D)}')
    return model, np.concatenate([D, np.zeros(n - len(D))])


@dataclass(eq=False)
class Camera:
    """A calibrated camera: intrinsics K, distortion D and its optical frame's pose in world."""

    name: str
    width: int
    height: int
    K: np.ndarray
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))
    distortion_model: str = 'plumb_bob'
    R_world_cam: np.ndarray = field(default_factory=lambda: np.eye(3))
    t_world_cam: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _ray_cache: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        """Validate and convert every field to its canonical numpy form."""
        self.name = str(self.name)
        self.width, self.height = int(self.width), int(self.height)
        if self.width <= 0 or self.height <= 0:
            raise ValueError(
                f'camera {self.name!r}: image size must be positive, got '
                f'{self.width}x{self.height}'
            )
        K = np.array(self.K, dtype=float)
        if K.size != 9:
            raise ValueError(f'camera {self.name!r}: K needs 9 values, got {K.size}')
        K = K.reshape(3, 3)
        if not is_camera_matrix(K):
            raise ValueError(
                f'camera {self.name!r}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] '
                f'with fx, fy > 0, got {K.tolist()}'
            )
        self.K = K
        D = np.array(self.D if self.D is not None else [], dtype=float).ravel()
        self.distortion_model, self.D = _normalise_model(self.distortion_model, D)
        R = np.array(self.R_world_cam, dtype=float).reshape(3, 3)
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(
                f'camera {self.name!r}: R_world_cam is not a rotation matrix: {R.tolist()}'
            )
        self.R_world_cam = R
        self.t_world_cam = np.array(self.t_world_cam, dtype=float).reshape(3)

    def __eq__(self, other: object) -> bool:
        """Exact equality of name, size, intrinsics, distortion and pose."""
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            self.name == other.name
            and self.width == other.width
            and self.height == other.height
            and self.distortion_model == other.distortion_model
            and np.array_equal(self.K, other.K)
            and np.array_equal(self.D, other.D)
            and np.array_equal(self.R_world_cam, other.R_world_cam)
            and np.array_equal(self.t_world_cam, other.t_world_cam)
        )

    # Mutable and compared by value, so unhashable: defining __eq__ leaves __hash__ None.

    # ----------------------------------------------------------------- basics
    @property
    def centre(self) -> np.ndarray:
        """Optical centre in world (= t_world_cam), the origin of the paper's camera frame C."""
        return self.t_world_cam

    @property
    def coefficients(self) -> np.ndarray:
        """The 8 OpenCV rational-model coefficients k1, k2, p1, p2, k3, k4, k5, k6, zero-padded."""
        return np.concatenate([self.D, np.zeros(8 - len(self.D))])

    @property
    def has_distortion(self) -> bool:
        """True when any distortion coefficient is non-zero."""
        return bool(np.any(self.D))

    def world_to_camera(self, P: np.ndarray) -> np.ndarray:
        """World points (..., 3) in the optical frame: Pc = R^T (P - t) (eq. 5 inverted)."""
        return (np.asarray(P, float) - self.t_world_cam) @ self.R_world_cam

    def camera_to_world(self, Pc: np.ndarray) -> np.ndarray:
        """Optical-frame points (..., 3) in world: P = t + R Pc (eq. 5)."""
        return np.asarray(Pc, float) @ self.R_world_cam.T + self.t_world_cam

    # ------------------------------------------------------------- projection
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Distorted normalised coordinates (..., 2) of ideal normalised coordinates (..., 2)."""
        return self._distort(np.asarray(xy, float), jacobian=False)[0]

    @overload
    def _distort(self, xy: np.ndarray, jacobian: Literal[False]) -> tuple[np.ndarray, None]: ...

    @overload
    def _distort(
        self, xy: np.ndarray, jacobian: Literal[True]
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def _distort(self, xy: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Distortion of normalised coordinates (..., 2) and optionally its Jacobian (..., 2, 2).

        The Jacobian is None when not asked for.
        """
        if not self.has_distortion:
            eye = np.broadcast_to(np.eye(2), xy.shape[:-1] + (2, 2)) if jacobian else None
            return xy, eye
        k1, k2, p1, p2, k3, k4, k5, k6 = self.coefficients
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        radial = num / den
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        out = np.stack([xd, yd], -1)
        if not jacobian:
            return out, None
        d_num = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        d_den = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
        g = (d_num * den - num * d_den) / (den * den)  # d radial / d r2
        dxd_dx = radial + 2.0 * x * x * g + 2.0 * p1 * y + 6.0 * p2 * x
        dyd_dy = radial + 2.0 * y * y * g + 6.0 * p1 * y + 2.0 * p2 * x
        cross = 2.0 * x * y * g + 2.0 * p1 * x + 2.0 * p2 * y
        J = np.stack([np.stack([dxd_dx, cross], -1), np.stack([cross, dyd_dy], -1)], -2)
        return out, J

    def _to_pixels(self, xd: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of distorted normalised coordinates: the affine part of K."""
        K = self.K
        u = K[0, 0] * xd[..., 0] + K[0, 1] * xd[..., 1] + K[0, 2]
        v = K[1, 1] * xd[..., 1] + K[1, 2]
        return np.stack([u, v], -1)

    def _normalise(self, Pc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal normalised coordinates (x/z, y/z) (..., 2), NaN behind the camera.

        And the in-front mask.
        """
        z = Pc[..., 2]
        front = z > MIN_DEPTH
        with np.errstate(divide='ignore', invalid='ignore'):
            xy = Pc[..., :2] / np.where(front, z, np.nan)[..., None]
        return xy, front

    def project_camera(self, Pc: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of optical-frame points (..., 3) with distortion (eq. 6).

        NaN when z <= MIN_DEPTH.
        """
        xy, _ = self._normalise(np.asarray(Pc, float))
        return self._to_pixels(self._distort(xy, jacobian=False)[0])

    def project(self, P_world: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of world points (..., 3) with distortion (eq. 5, 6).

        NaN behind the camera.
        """
        return self.project_camera(self.world_to_camera(P_world))

    def projection_jacobian_camera(self, Pc: np.ndarray) -> np.ndarray:
        """H.

        d(u, v)/d(optical-frame point) (..., 2, 3), eq. 8 extended by distortion and K; NaN behind.
        """
        Pc = np.asarray(Pc, float)
        if (
            not self.has_distortion
        ):  # H = A perspective_jacobian(Pc), written out (no stacked 2x2 products)
            return self._affine_perspective_jacobian(Pc)
        xy, _ = self._normalise(Pc)
        _, J_dist = self._distort(xy, jacobian=True)
        A = self.K[:2, :2]  # fx, skew; 0, fy
        return A @ J_dist @ perspective_jacobian(Pc)  # eq. 8 with f = 1, then distortion, then K

    def _affine_perspective_jacobian(self, Pc: np.ndarray) -> np.ndarray:
        """K[:2, :2] @ perspective_jacobian(Pc) (..., 2, 3) elementwise.

        The Jacobian without distortion.
        """
        x, y, z = Pc[..., 0], Pc[..., 1], Pc[..., 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            inv_z = np.where(z > MIN_DEPTH, 1.0 / z, np.nan)
        cx, cy = -x * inv_z * inv_z, -y * inv_z * inv_z
        fx, skew, fy = self.K[0, 0], self.K[0, 1], self.K[1, 1]
        out = np.empty(Pc.shape[:-1] + (2, 3))
        out[..., 0, 0] = fx * inv_z
        out[..., 0, 1] = skew * inv_z
        out[..., 0, 2] = fx * cx + skew * cy
        out[..., 1, 0] = 0.0 * inv_z
        out[..., 1, 1] = fy * inv_z
        out[..., 1, 2] = fy * cy
        return out

    def project_with_jacobian(self, P_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (..., 2) and d(u, v)/d(world point) (..., 2, 3) = H R^-1 (eq. 9's H C_R^-1)."""
        Pc = self.world_to_camera(P_world)
        uv = self.project_camera(Pc)
        J = self.projection_jacobian_camera(Pc) @ self.R_world_cam.T  # eq. 9: R^-1 = R^T
        return uv, J

    # ------------------------------------------------------------------ rays
    def undistort(self, xd: np.ndarray) -> np.ndarray:
        """Ideal normalised coordinates (..., 2) of distorted ones.

        cv2.undistortPoints, then Newton polish.
        """
        xd = np.asarray(xd, float)
        if not self.has_distortion or xd.size == 0:
            return xd.copy()
        flat = xd.reshape(-1, 2)
        xy = cv2.undistortPoints(
            np.ascontiguousarray(flat[:, None, :]),
            np.eye(3),
            self.coefficients,
            None,
            np.eye(3),
            np.eye(3),
            _UNDISTORT_CRITERIA,
        ).reshape(-1, 2)
        for _ in range(3):  # Newton steps on distort(xy) = xd, kept only if they help
            pred, J = self._distort(xy, jacobian=True)
            res = pred - flat
            with np.errstate(divide='ignore', invalid='ignore'):
                step = np.linalg.solve(J, res[..., None])[..., 0]
            cand = xy - step
            better = np.sum((self._distort(cand, False)[0] - flat) ** 2, -1) < np.sum(
                res * res, -1
            )
            xy = np.where(better[:, None], cand, xy)
        return xy.reshape(xd.shape)

    def ideal_coordinates(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Return undistorted normalised coordinates (..., 2) of pixels (u, v) (broadcast)."""
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        K = self.K
        yd = (v - K[1, 2]) / K[1, 1]  # K^-1 applied exactly, skew included
        xd = (u - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        return self.undistort(np.stack([xd, yd], -1))

    def pixel_rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Return unit ray directions in world (..., 3) through pixels (u, v) (broadcast).

        Undistorted.
        """
        xy = self.ideal_coordinates(u, v)
        d = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return d @ self.R_world_cam.T

    def pixel_grid_rays(self, scale: float = 1.0) -> np.ndarray:
        """Read-only world ray directions (H', W', 3) through every pixel centre.

        The pixels are those of the image resized by ``scale``.
        """
        width, height = self._scaled_size(scale)
        key = (
            float(scale),
            self.width,
            self.height,
            self.K.tobytes(),
            self.D.tobytes(),
            self.R_world_cam.tobytes(),
        )
        rays = self._ray_cache.get(key)
        if rays is None:
            u_small, v_small = np.meshgrid(
                np.arange(width, dtype=float), np.arange(height, dtype=float)
            )
            rays = self.pixel_rays((u_small + 0.5) / scale - 0.5, (v_small + 0.5) / scale - 0.5)
            rays.setflags(write=False)
            if len(self._ray_cache) >= 8:
                self._ray_cache.clear()
            self._ray_cache[key] = rays
        return rays

    # ------------------------------------------------------------ resizing
    def _scaled_size(self, scale: float) -> tuple[int, int]:
        """Width and height of the image resized by ``scale``, rounded."""
        scale = float(scale)
        if not scale > 0.0:
            raise ValueError(f'scale must be positive, got {scale}')
        return max(int(round(self.width * scale)), 1), max(int(round(self.height * scale)), 1)

    def scaled(self, scale: float) -> 'Camera':
        """Return the camera for the image resized by ``scale``.

        Pixels map as u_small = (u + 0.5) * scale - 0.5.
        """
        width, height = self._scaled_size(scale)
        K = self.K.copy()
        K[0, :2] *= scale
        K[1, 1] *= scale
        K[0, 2] = (K[0, 2] + 0.5) * scale - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
        return Camera(
            self.name,
            width,
            height,
            K,
            self.D.copy(),
            self.distortion_model,
            self.R_world_cam.copy(),
            self.t_world_cam.copy(),
        )

    # --------------------------------------------------------- construction
    @classmethod
    def look_at(
        cls,
        name: str,
        eye,
        target,
        up=(0.0, 0.0, 1.0),
        *,
        width: int,
        height: int,
        fx: float,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        D=(),
        distortion_model: str = 'plumb_bob',
    ) -> 'Camera':
        """Return a camera at ``eye`` looking at ``target``.

        Image y along -``up`` (REP 103 optical frame), for studios.
        """
        # A view parallel to ``up`` uses the world axis least aligned with it as up instead.
        # cx, cy default to the image centre ((width - 1) / 2, (height - 1) / 2); fy to fx.
        eye, target, up = (np.asarray(a, float).reshape(3) for a in (eye, target, up))
        z = target - eye
        if np.linalg.norm(z) < 1e-12:
            raise ValueError(f'camera {name!r}: eye and target coincide')
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9 * max(float(np.linalg.norm(up)), 1e-300):
            x = np.cross(z, np.eye(3)[np.argmin(np.abs(z))])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack(
            [x, y, z], axis=1
        )  # columns: optical x (right), y (down), z (forward) in world
        fy = fx if fy is None else fy
        cx = (width - 1) / 2.0 if cx is None else cx
        cy = (height - 1) / 2.0 if cy is None else cy
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(name, width, height, K, np.asarray(D, float), distortion_model, R, eye)

    def to_dict(self) -> dict:
        """Plain-python studio YAML entry.

        Keys: name, width, height, distortion_model, K (9), D, pose.
        """
        return {
            'name': self.name,
            'width': self.width,
            'height': self.height,
            'distortion_model': self.distortion_model,
            'K': [float(v) for v in self.K.ravel()],
            'D': [float(v) for v in self.D],
            'pose': {
                'position': [float(v) for v in self.t_world_cam],
                'orientation': [float(v) for v in matrix_to_quat(self.R_world_cam)],
            },
        }

    @classmethod
    def from_dict(cls, data: dict) -> 'Camera':
        """Camera from a studio YAML entry (see :meth:`to_dict`).

        Pose defaults to the world origin.
        """
        pose = data.get('pose') or {}
        q = pose.get('orientation', (0.0, 0.0, 0.0, 1.0))
        if len(q) != 4:
            raise ValueError(f'pose.orientation must be a quaternion [qx, qy, qz, qw], got {q}')
        return cls(
            data['name'],
            data['width'],
            data['height'],
            data['K'],
            np.asarray(data.get('D') or [], dtype=float),
            data.get('distortion_model', 'plumb_bob'),
            quat_to_matrix(q),
            pose.get('position', (0.0, 0.0, 0.0)),
        )

    def to_camera_info_fields(self, frame_id: str | None = None) -> dict:
        """sensor_msgs/CameraInfo fields as plain python.

        Width, height, distortion_model, d, k, r, p, frame_id.
        """
        P = np.hstack([self.K, np.zeros((3, 1))])  # monocular: P = [K | 0]
        return {
            'width': self.width,
            'height': self.height,
            'distortion_model': 'plumb_bob'
            if self.distortion_model == 'none'
            else self.distortion_model,
            'd': [float(v) for v in self.D] if self.distortion_model != 'none' else [0.0] * 5,
            'k': [float(v) for v in self.K.ravel()],
            'r': [float(v) for v in np.eye(3).ravel()],
            'p': [float(v) for v in P.ravel()],
            'frame_id': frame_id if frame_id is not None else f'{self.name}_optical_frame',
        }

    @classmethod
    def from_camera_info_fields(
        cls,
        width: int,
        height: int,
        distortion_model: str,
        d,
        k,
        r=None,
        p=None,
        frame_id: str = '',
        *,
        name: str | None = None,
        R_world_cam=None,
        t_world_cam=None,
    ) -> 'Camera':
        """Camera from sensor_msgs/CameraInfo fields.

        The pose (not in CameraInfo) comes from the studio.
        """
        # r and p (rectification, rectified projection) do not affect raw-image projection:
        # length-checked only.
        # The name defaults to frame_id without an '_optical_frame' suffix.
        k = np.asarray(k, float)
        if k.size != 9 or not np.any(k):
            raise ValueError(f'CameraInfo {frame_id!r}: uncalibrated or malformed K {k.tolist()}')
        for label, value, size in (('R', r, 9), ('P', p, 12)):
            if value is not None and len(value) not in (0, size):
                raise ValueError(
                    f'CameraInfo {frame_id!r}: {label} needs {size} values, got {len(value)}'
                )
        if name is None:
            name = (
                frame_id[: -len('_optical_frame')]
                if frame_id.endswith('_optical_frame')
                else frame_id
            )
        return cls(
            name,
            width,
            height,
            k.reshape(3, 3),
            np.asarray(d, float),
            distortion_model,
            np.eye(3) if R_world_cam is None else R_world_cam,
            np.zeros(3) if t_world_cam is None else t_world_cam,
        )


def intrinsics_problem(
    width: int, height: int, distortion_model: str, d, k, expected: Camera | None = None
) -> str | None:
    """Return why CameraInfo-like intrinsics cannot be this camera, or None when they can.

    They must make a camera (positive size and focal lengths, the principal point near the
    image, a known distortion model with its number of finite coefficients) and, given the
    studio's ``expected`` camera, agree with it (size, K, distortion model).
    """
    d, k = np.asarray(d, float).ravel(), np.asarray(k, float).ravel()
    if int(width) <= 0 or int(height) <= 0:
        return f'image size {width}x{height}'
    if k.size != 9 or not np.all(np.isfinite(k)):
        return f'K {k.tolist()} is not 9 finite numbers'
    if not is_camera_matrix(k.reshape(3, 3)):
        return f'K {k.tolist()} is not a camera matrix (positive focal lengths, last row 0 0 1)'
    if not (-0.5 * width <= k[2] <= 1.5 * width and -0.5 * height <= k[5] <= 1.5 * height):
        return f'principal point ({k[2]:g}, {k[5]:g}) far from the {width}x{height} image'
    if not np.all(np.isfinite(d)):
        return f'D {d.tolist()} is not finite'
    try:
        model, _ = _normalise_model(distortion_model, d)
    except ValueError as exc:
        return str(exc)
    if model != 'none' and len(d) not in (N_COEFFS[model], 4 if model == 'plumb_bob' else -1):
        return f'{model} takes {N_COEFFS[model]} distortion coefficients, got {len(d)}'
    if expected is not None:
        if (int(width), int(height)) != (expected.width, expected.height):
            return (
                f"size {width}x{height} differs from the studio's "
                f'{expected.width}x{expected.height}'
            )
        if model != expected.distortion_model and (np.any(d) or expected.has_distortion):
            return (
                f"distortion model {model} differs from the studio's {expected.distortion_model}"
            )
    return None
