"""Simulated scenarios: the camera rigs and the motions the simulator renders.

- ``studio-arm``: three mutually orthogonal cameras (front, left side, overhead)
  and a standing subject moving the right arm in 3D with elbow flexion and
  forearm rotation, as in Kakadiaris & Metaxas §5.
- ``studio-walk``: the same studio, a person walking with the gait model along
  a circular arc, so the heading turns and the legs occlude each other.
- ``street-walk``: Rohr's scene: one camera about 11 m from a straight path
  parallel to its image plane, 25 frames/s, 1 s and 1.6 m per gait cycle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from memo_ros.core.geometry.body import Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.walking.gait import WalkingModel

Trajectory = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray | None]]


@dataclass
class Scenario:
    """A rig, a frame rate, a default length and the body's motion q(t).

    And gait phase, if walking.
    """

    name: str
    cameras: list[Camera]
    frame_rate: float
    frames: int
    trajectory: Trajectory
    description: str
    empty_frames: int = 0  # frames of the empty scene before the subject appears (clean plate)
    contour_parameters: dict = field(
        default_factory=dict
    )  # contour_node parameters suited to the scene
    node_parameters: dict = field(
        default_factory=dict
    )  # other nodes' parameters, by node name (walker_node)

    def coordinates(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Generalized coordinates (N, n) and gait phase (N,) or None at ``times``.

        s from the start.
        """
        return self.trajectory(np.asarray(times, float))

    def velocities(self, times: np.ndarray, dt: float = 1e-4) -> np.ndarray:
        """Time derivative of the generalized coordinates.

        Central differences of the smooth motion.
        """
        after, _ = self.coordinates(times + dt / 2)
        before, _ = self.coordinates(times - dt / 2)
        return (after - before) / dt


def studio_cameras(width: int = 640, height: int = 480) -> list[Camera]:
    """Three mutually orthogonal cameras: in front of, left of, and above the studio's centre."""
    f = 650.0 * width / 640.0
    return [
        Camera.look_at(
            'cam_front',
            eye=(4.0, 0.0, 1.0),
            target=(0.0, 0.0, 1.0),
            width=width,
            height=height,
            fx=f,
        ),
        Camera.look_at(
            'cam_side',
            eye=(0.0, 4.0, 1.0),
            target=(0.0, 0.0, 1.0),
            width=width,
            height=height,
            fx=f,
        ),
        Camera.look_at(
            'cam_top',
            eye=(0.0, 0.0, 4.5),
            target=(0.0, 0.0, 0.0),
            up=(1.0, 0.0, 0.0),
            width=width,
            height=height,
            fx=f,
        ),
    ]


def street_camera(width: int = 640, height: int = 480) -> list[Camera]:
    """Rohr's camera.

    11 m from the path (world x axis), slightly above and looking down at the walker.
    """
    f = 1000.0 * width / 640.0
    return [
        Camera.look_at(
            'cam_street',
            eye=(0.0, -11.0, 1.5),
            target=(0.0, 0.0, 0.9),
            width=width,
            height=height,
            fx=f,
        )
    ]


def arm_motion(body: Body, duration: float) -> Trajectory:
    """Right arm lifted forward and sideways, elbow bending, forearm twisting.

    The rest stands still.
    """
    base = body.neutral()
    idx = body.coordinate_index

    def trajectory(t: np.ndarray):
        s = 2 * np.pi * t / duration
        q = np.repeat(base[None], len(t), 0)
        q[:, idx('shoulder_r_y')] = 0.75 * (1 - np.cos(s))  # flexion up to 1.5 rad
        q[:, idx('shoulder_r_x')] = -0.45 * np.sin(s) ** 2 - 0.05  # abduction
        q[:, idx('shoulder_r_z')] = 0.35 * np.sin(s)  # internal/external rotation
        q[:, idx('elbow_r_y')] = 0.8 * (1 - np.cos(1.5 * s))  # elbow flexion up to 1.6 rad
        q[:, idx('elbow_r_z')] = 1.2 * np.sin(s)  # forearm pronation/supination
        q[:, idx('shoulder_l_x')] = 0.05  # left arm clear of the torso
        return q, None

    return trajectory


def arc_walk(
    body: Body,
    radius: float,
    speed: float,
    start_angle: float,
    cycle_length: float,
    phase0: float = 0.0,
) -> Trajectory:
    """Return walking counter-clockwise on a circle around the origin, facing along the tangent."""
    walker = WalkingModel(body)

    def trajectory(t: np.ndarray):
        angle = start_angle + speed * t / radius
        phase = np.mod(phase0 + speed * t / cycle_length, 1.0)
        q = walker.coordinates(
            phase, radius * np.cos(angle), radius * np.sin(angle), angle + np.pi / 2
        )
        return q, phase

    return trajectory


def line_walk(
    body: Body, start: float, speed: float, cycle_length: float, phase0: float = 0.0
) -> Trajectory:
    """Return walking along +x on the line y = 0 (Rohr's pedestrian)."""
    walker = WalkingModel(body)

    def trajectory(t: np.ndarray):
        phase = np.mod(phase0 + speed * t / cycle_length, 1.0)
        return walker.coordinates(phase, start + speed * t, 0.0, 0.0), phase

    return trajectory


def make_scenario(
    name: str,
    body: Body,
    width: int = 640,
    height: int = 480,
    frames: int | None = None,
    frame_rate: float | None = None,
) -> Scenario:
    """Build a named scenario; unknown names raise ValueError listing the known ones."""
    if name == 'studio-arm':
        rate = frame_rate or 30.0
        n = frames or 90
        return Scenario(
            name,
            studio_cameras(width, height),
            rate,
            n,
            arm_motion(body, n / rate),
            'three orthogonal cameras, right arm moving in 3D with elbow flexion and forearm '
            'rotation',
            STUDIO_EMPTY_FRAMES,
            _studio_contours(),
        )
    if name == 'studio-walk':
        rate = frame_rate or 30.0
        n = frames or 90
        return Scenario(
            name,
            studio_cameras(width, height),
            rate,
            n,
            arc_walk(
                body, radius=1.0, speed=1.1, start_angle=np.radians(-100.0), cycle_length=1.3
            ),
            'three orthogonal cameras, walking on a 1 m circle (turning), legs occluding each '
            'other',
            STUDIO_EMPTY_FRAMES,
            _studio_contours(),
        )
    if name == 'street-walk':
        rate = frame_rate or 25.0
        n = frames or 75
        speed = 1.6  # m/s: 1.6 m per cycle at one cycle per second (Rohr §6)
        return Scenario(
            name,
            street_camera(width, height),
            rate,
            n,
            line_walk(body, start=-0.5 * speed * n / rate, speed=speed, cycle_length=1.6),
            "Rohr's street: one camera 11 m from a path parallel to the image plane",
            0,
            {
                'segmenter': 'background',
                'threshold': 4.0,
                'background_frames': 15,
                'keep_regions': 'largest',
            },
            {'walker_node': dict(WALKER_PARAMETERS)},
        )
    raise ValueError(f'unknown scenario {name!r}; known: {", ".join(SCENARIOS)}')


SCENARIOS = ('studio-arm', 'studio-walk', 'street-walk')
# a studio session starts with the empty studio, so the background can be learnt before the subject
# enters
# the street's walker_node (Rohr's MEMO): its presence in a studio file makes `memo-ros launch`
# start it
WALKER_PARAMETERS = {'init_first': 2, 'init_last': 14}
STUDIO_EMPTY_FRAMES = 10


def _studio_contours() -> dict:
    """contour_node parameters for the studio.

    Background learnt over the empty frames, every region kept.
    """
    return {
        'segmenter': 'background',
        'threshold': 1.0,
        'background_frames': STUDIO_EMPTY_FRAMES,
        'keep_regions': 'all',
    }
