"""Simulated scenarios: the camera rigs and the motions the simulator renders.

- ``studio-arm``: three mutually orthogonal cameras (front, left side, overhead)
  and a standing subject moving the right arm in 3D with elbow flexion and
  forearm rotation, as in Kakadiaris & Metaxas §5.
- ``studio-walk``: the same studio, a person walking with the gait model along
  a circular arc, so the heading turns and the legs occlude each other.
- ``street-walk``: Rohr's scene: one camera about 11 m from a straight path
  parallel to its image plane, 25 frames/s, 1 s and 1.6 m per gait cycle.
- ``studio-dance``: fast whole-body motion in 4 s: both arms raised overhead at
  different times, a fast forward kick of each leg, a full turn about the
  vertical in 1.2 s, a small squat and a small translation, from a chosen start
  heading, on the orthogonal rig or a non-orthogonal ring of 4 cameras (``ring4``).

The studio scenarios take ``rig`` (:data:`RIGS`); ``studio-dance`` also ``heading``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike

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

        Central differences of the smooth motion; the angles' differences are wrapped into
        (-pi, pi], so a yaw that jumps from pi to -pi (the same rotation) keeps the turn's rate.
        """
        after, _ = self.coordinates(times + dt / 2)
        before, _ = self.coordinates(times - dt / 2)
        step = after - before
        step[..., 3:] = np.pi - np.mod(np.pi - step[..., 3:], 2 * np.pi)
        return step / dt


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


def ring_cameras(
    azimuths_deg: ArrayLike,
    distances: ArrayLike,
    heights: ArrayLike,
    width: int = 640,
    height: int = 480,
    prefix: str = 'cam_ring',
) -> list[Camera]:
    """Cameras round the studio looking at (0, 0, 1) m: one per azimuth, distance and height.

    A ring sees the subject from directions no orthogonal rig has; the focal length scales with
    the width like the studio's (650 px at 640).
    """
    azimuths = np.radians(np.asarray(azimuths_deg, float))
    out = np.broadcast_to(np.asarray(distances, float), azimuths.shape)
    up = np.broadcast_to(np.asarray(heights, float), azimuths.shape)
    eyes = np.stack([out * np.cos(azimuths), out * np.sin(azimuths), up], axis=-1)
    f = 650.0 * width / 640.0
    return [
        Camera.look_at(f'{prefix}{k}', eye, (0.0, 0.0, 1.0), width=width, height=height, fx=f)
        for k, eye in enumerate(eyes)
    ]


def ring4_cameras(width: int = 640, height: int = 480) -> list[Camera]:
    """Four cameras at uneven azimuths, distances and heights, unlike the axis-aligned studio."""
    return ring_cameras(RING4_AZIMUTHS_DEG, RING4_DISTANCES, RING4_HEIGHTS, width, height)


def rig_cameras(rig: str, width: int = 640, height: int = 480) -> list[Camera]:
    """Return a studio rig's cameras by name (:data:`RIGS`); unknown names raise ValueError."""
    if rig == 'orthogonal':
        return studio_cameras(width, height)
    if rig == 'ring4':
        return ring4_cameras(width, height)
    raise ValueError(f'unknown rig {rig!r}; known: {", ".join(RIGS)}')


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


def _bump(t: np.ndarray, start: float, width: float) -> np.ndarray:
    """Return a raised cosine from 0 up to 1 and back over [start, start + width], 0 elsewhere.

    Its derivative is continuous (0 at both ends), so the motion's velocities exist.
    """
    u = np.clip((t - start) / width, 0.0, 1.0)
    return 0.5 * (1.0 - np.cos(2.0 * np.pi * u))


def _ramp(t: np.ndarray, start: float, width: float) -> np.ndarray:
    """Return a half cosine from 0 to 1 over [start, start + width]: C1, flat before and after."""
    u = np.clip((t - start) / width, 0.0, 1.0)
    return 0.5 * (1.0 - np.cos(np.pi * u))


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Return ``angle`` wrapped into (-pi, pi], rad."""
    return np.pi - np.mod(np.pi - np.asarray(angle, float), 2.0 * np.pi)


def dance_motion(body: Body, heading: float = 0.0) -> Trajectory:
    """Fast whole-body motion in 4 s (:data:`DANCE_SECONDS`) from the start ``heading`` (rad).

    Both arms raised overhead and lowered at different times, a fast forward kick of each leg
    (hip flexion to 1.3 rad in 0.4 s, the knee bending and straightening), a full turn about the
    vertical in 1.2 s with a small step sideways, then a squat lowering the pelvis by 0.1 m with
    the feet flat.  Every coordinate is C1 in time; the yaw is wrapped into (-pi, pi].  After
    4 s the subject stands still.
    """
    base = body.neutral()
    idx = body.coordinate_index
    offsets = body.joint_offsets
    # from the hip to the ankle along the straight leg
    leg = float(np.linalg.norm(offsets['knee_l']) + np.linalg.norm(offsets['ankle_l']))

    def trajectory(t: np.ndarray):
        s = np.asarray(t, float)
        q = np.repeat(base[None], len(s), 0)
        move = {name: _bump(s, start, width) for name, (start, width) in DANCE_MOVES.items()}
        turn = _ramp(s, *DANCE_MOVES['turn'])  # a full turn in 1.2 s
        step = _ramp(s, *DANCE_MOVES['step'])
        q[:, idx('shoulder_l_x')] = 0.05  # the arms clear of the torso (arm_motion)
        q[:, idx('shoulder_r_x')] = -0.05
        for side, arm in (('l', move['left arm overhead']), ('r', move['right arm overhead'])):
            q[:, idx(f'shoulder_{side}_y')] = 2.7 * arm  # forward and up to 155 degrees: overhead
            q[:, idx(f'elbow_{side}_y')] = 0.15 + 0.35 * arm  # elbows a little bent throughout
        # the squat: hips and ankles flex by a, the knees by 2a, so the shanks lean as far forwards
        # as the thighs back and the feet stay flat; the pelvis sinks by leg (1 - cos a), 0.1 m
        a = 0.49 * move['squat']
        for side, name in (('r', 'right kick'), ('l', 'left kick')):
            kick = move[name]  # up in 0.4 s, down in 0.4 s
            chamber = _bump(s, DANCE_MOVES[name][0], 0.5)  # the knee bends before the hip
            hip = 1.3 * kick
            knee = -1.1 * chamber - 0.3 * kick
            q[:, idx(f'hip_{side}_y')] = hip + a
            q[:, idx(f'knee_{side}_y')] = knee - 2.0 * a
            q[:, idx(f'ankle_{side}_y')] = a - (hip + knee)  # the foot level: no toe in the floor
        q[:, 2] = base[2] - leg * (1.0 - np.cos(a))
        q[:, 0] = 0.15 * step  # a small step forward-sideways during the turn
        q[:, 1] = -0.1 * step
        q[:, 5] = wrap_angle(heading + 2.0 * np.pi * turn)
        return q, None

    return trajectory


def dance_moves(start: float, end: float | None = None) -> list[str]:
    """Return the studio-dance moves (:data:`DANCE_MOVES`) under way in [start, end] s.

    To say what the subject was doing where a tracker failed.
    """
    end = start if end is None else end
    return [name for name, (t0, width) in DANCE_MOVES.items() if t0 < end and start < t0 + width]


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
    *,
    heading: float | None = None,
    rig: str | None = None,
) -> Scenario:
    """Build a named scenario; unknown names raise ValueError listing the known ones.

    ``rig`` (:data:`RIGS`, default orthogonal) chooses a studio scenario's cameras and
    ``heading`` (rad, default 0) where studio-dance starts facing; options a scenario does not
    take raise ValueError.
    """
    if heading is not None and name != 'studio-dance':
        raise ValueError(f'scenario {name!r} takes no heading (only studio-dance does)')
    if rig is not None and not name.startswith('studio-'):
        raise ValueError(f'scenario {name!r} has its own camera; rigs are for the studio')
    if rig is not None and rig not in RIGS:
        raise ValueError(f'unknown rig {rig!r}; known: {", ".join(RIGS)}')
    rig_name = 'orthogonal' if rig is None else rig
    rig_text = 'three orthogonal cameras' if rig_name == 'orthogonal' else RING4_TEXT
    if name == 'studio-dance':
        rate = frame_rate or 30.0
        n = frames or int(round(DANCE_SECONDS * rate))
        start = 0.0 if heading is None else float(heading)
        if not np.isfinite(start):
            raise ValueError(f'heading must be finite, not {heading}')
        return Scenario(
            name,
            rig_cameras(rig_name, width, height),
            rate,
            n,
            dance_motion(body, start),
            f'{rig_text}, fast whole-body motion from heading {np.degrees(start):.0f} deg: arms '
            'overhead, a kick of each leg, a full turn in 1.2 s, a squat',
            STUDIO_EMPTY_FRAMES,
            _studio_contours(),
        )
    if name == 'studio-arm':
        rate = frame_rate or 30.0
        n = frames or 90
        return Scenario(
            name,
            rig_cameras(rig_name, width, height),
            rate,
            n,
            arm_motion(body, n / rate),
            f'{rig_text}, right arm moving in 3D with elbow flexion and forearm rotation',
            STUDIO_EMPTY_FRAMES,
            _studio_contours(),
        )
    if name == 'studio-walk':
        rate = frame_rate or 30.0
        n = frames or 90
        return Scenario(
            name,
            rig_cameras(rig_name, width, height),
            rate,
            n,
            arc_walk(
                body, radius=1.0, speed=1.1, start_angle=np.radians(-100.0), cycle_length=1.3
            ),
            f'{rig_text}, walking on a 1 m circle (turning), legs occluding each other',
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


SCENARIOS = ('studio-arm', 'studio-walk', 'street-walk', 'studio-dance')
DANCE_SECONDS = 4.0  # studio-dance's motion; a longer sequence ends standing still
# studio-dance's timeline: each move's start and duration, s (arms and kicks rise in half of it)
DANCE_MOVES: dict[str, tuple[float, float]] = {
    'left arm overhead': (0.2, 1.1),
    'right kick': (0.7, 0.8),
    'right arm overhead': (1.0, 1.1),
    'left kick': (1.6, 0.8),
    'step': (1.8, 2.0),
    'turn': (2.2, 1.2),
    'squat': (2.9, 1.0),
}
RIGS = ('orthogonal', 'ring4')  # the studio scenarios' camera rigs
# ring4: azimuths 80-95 degrees apart, at different distances and heights, as a rig might be put up
# in a room: its optical axes meet at 80, 86, 92, 94, 145 and 165 degrees, none along a world axis
RING4_AZIMUTHS_DEG = (20.0, 115.0, 205.0, 300.0)
RING4_DISTANCES = (4.0, 4.5, 3.6, 4.2)
RING4_HEIGHTS = (1.2, 2.6, 1.7, 2.1)
RING4_TEXT = 'four cameras on an uneven ring (20, 115, 205, 300 deg; 3.6-4.5 m; 1.2-2.6 m high)'
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
