"""Grey-value pictures of the rendered body over a textured, static background.

The background is a tiled floor (z = 0) and a mottled far wall, both fixed in
world so that every camera's background is static and consistent; the body is
shaded (Lambert, one directional light plus ambient) with per-part clothing
albedo.  Sensor noise, blur and slow lighting changes are options, so the
segmentation has real work to do.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import Rendering, render

# clothing: light shirt, skin, dark trousers, black shoes (grey levels 0..255)
PART_ALBEDO = {
    'torso': 165.0,
    'head': 200.0,
    'upper_arm_l': 150.0,
    'forearm_l': 185.0,
    'hand_l': 205.0,
    'upper_arm_r': 150.0,
    'forearm_r': 185.0,
    'hand_r': 205.0,
    'thigh_l': 75.0,
    'shank_l': 85.0,
    'foot_l': 35.0,
    'thigh_r': 75.0,
    'shank_r': 85.0,
    'foot_r': 35.0,
}
# colour tint per part for colour encodings (B, G, R multipliers), normalised below to unit luma
# so that a colour stream converts to the same grey as the mono8 one
_RAW_TINT = {
    'torso': (1.25, 0.85, 0.75),
    'upper_arm_l': (1.25, 0.85, 0.75),
    'upper_arm_r': (1.25, 0.85, 0.75),
    'thigh_l': (1.3, 1.0, 0.8),
    'shank_l': (1.3, 1.0, 0.8),
    'thigh_r': (1.3, 1.0, 0.8),
    'shank_r': (1.3, 1.0, 0.8),
}
PART_TINT = {
    part: tuple(np.array(t) / (np.array(t) @ (0.114, 0.587, 0.299)))
    for part, t in _RAW_TINT.items()
}
LIGHT_DIRECTION = np.array([0.45, 0.35, 0.82])  # towards the light, world frame


@dataclass
class ImagingOptions:
    """Camera and lighting imperfections of the simulated images."""

    noise: float = 3.0  # sensor noise standard deviation, grey levels
    blur: float = 0.0  # Gaussian blur sigma in pixels (optics), 0 = off
    lighting_change: float = 0.0  # amplitude of the slow global gain change (0.1 = +-10 %)
    seed: int = 0


def background_image(camera: Camera, seed: int = 0) -> np.ndarray:
    """Return a static textured background (float32 grey levels) for ``camera``.

    Tiled floor and mottled wall.
    """
    rng = np.random.default_rng(seed)
    rays = camera.pixel_grid_rays(1.0)
    centre = np.asarray(camera.t_world_cam, float)
    with np.errstate(divide='ignore', invalid='ignore'):
        s = -centre[2] / rays[..., 2]
    floor = np.isfinite(s) & (s > 0)
    hit = centre + np.where(floor, s, 0.0)[..., None] * rays
    tiles = (np.floor(hit[..., 0] / 0.5) + np.floor(hit[..., 1] / 0.5)) % 2
    floor_img = 105.0 + 30.0 * tiles
    # wall: direction-dependent mottling, identical for every frame
    azimuth = np.arctan2(rays[..., 1], rays[..., 0])
    elevation = np.arcsin(np.clip(rays[..., 2], -1, 1))
    wall_img = (
        125.0
        + 25.0 * np.sin(7 * azimuth) * np.cos(5 * elevation)
        + 15.0 * np.sin(23 * azimuth + 3)
    )
    image = np.where(floor, floor_img, wall_img)
    noise = rng.normal(0.0, 1.0, (camera.height // 4 + 1, camera.width // 4 + 1)).astype(
        np.float32
    )
    texture = cv2.resize(
        cv2.GaussianBlur(noise, (0, 0), 1.5),
        (camera.width, camera.height),
        interpolation=cv2.INTER_CUBIC,
    )
    return (image + 18.0 * texture).astype(np.float32)


def shade_body(rendering: Rendering, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Grey levels of the body pixels (float32, 0 elsewhere) and the body mask.

    From labels and normals.
    """
    if rendering.normal is None:
        raise ValueError('shade_body needs a rendering with normals')
    mask = rendering.label > 0
    albedo = np.zeros(len(PART_NAMES) + 1, np.float32)
    albedo[1:] = [PART_ALBEDO[p] for p in PART_NAMES]
    light_cam = np.asarray(camera.R_world_cam).T @ (
        LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION)
    )
    lambert = np.clip(rendering.normal @ light_cam.astype(np.float32), 0.0, 1.0)
    grey = albedo[rendering.label] * (0.45 + 0.55 * lambert)
    return np.where(mask, grey, 0.0).astype(np.float32), mask


def compose_frame(
    background: np.ndarray,
    rendering: Rendering,
    camera: Camera,
    options: ImagingOptions,
    frame_index: int,
    rng: np.random.Generator,
    colour: bool = False,
) -> np.ndarray:
    """One camera frame.

    Body over background, blur, lighting gain, noise; uint8 (H, W) or (H, W, 3) BGR.
    """
    body, mask = shade_body(rendering, camera)
    if colour:
        tint = np.ones((len(PART_NAMES) + 1, 3), np.float32)
        for i, name in enumerate(PART_NAMES):
            tint[i + 1] = PART_TINT.get(name, (1.0, 1.0, 1.0))
        image = np.where(
            mask[..., None], body[..., None] * tint[rendering.label], background[..., None]
        )
    else:
        image = np.where(mask, body, background)
    if options.blur > 0:
        image = cv2.GaussianBlur(image, (0, 0), options.blur)
    if options.lighting_change:
        image = image * (1.0 + options.lighting_change * np.sin(2 * np.pi * frame_index / 60.0))
    if options.noise > 0:
        image = image + rng.normal(0.0, options.noise, image.shape).astype(np.float32)
    return np.clip(image + 0.5, 0, 255).astype(np.uint8)


def simulated_frame(
    camera: Camera,
    body: Body,
    rotations: np.ndarray,
    origins: np.ndarray,
    background: np.ndarray,
    options: ImagingOptions,
    frame_index: int,
    rng: np.random.Generator,
    empty: bool = False,
    colour: bool = False,
    shape: str = 'cylinders',
) -> np.ndarray:
    """Render the posed body (none when ``empty``: the studio before him) into one frame.

    ``shape``: the parts' shape (:data:`memo_ros.core.geometry.render.SHAPES`).
    """
    rendering = render(
        camera,
        rotations,
        origins,
        body.semi_axes,
        body.lengths,
        normals=True,
        parts=np.zeros(0, int) if empty else None,
        shape=shape,
    )
    return compose_frame(background, rendering, camera, options, frame_index, rng, colour)
