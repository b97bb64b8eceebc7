"""Occluding contours (Kakadiaris §4.1 step 1), Rohr's edge lines (§4.3), the contour pipeline."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage

from memo_ros.core.geometry.body import load_studio_actor
from memo_ros.core.geometry.render import render
from memo_ros.core.simulation.imaging import ImagingOptions
from memo_ros.core.simulation.scenarios import make_scenario
from memo_ros.core.vision.contours import (
    CONTOUR_DTYPE,
    ContourPipeline,
    PipelineSettings,
    occluding_contours,
    smooth_closed_contour,
)
from memo_ros.core.vision.edges import (
    EDGE_DTYPE,
    edge_lines,
    edge_lines_in_boxes,
    merge_boxes,
)
from memo_ros.core.vision.segmentation import select_regions
from memo_ros.ros.bagio import grey_images
from memo_ros.tools.simulate import simulate

WIDTH, HEIGHT = 640, 480


def signed_distance(mask: np.ndarray) -> np.ndarray:
    """Distance to the silhouette's boundary (at pixel edges), negative inside, float32."""
    inside = ndimage.distance_transform_edt(mask)
    outside = ndimage.distance_transform_edt(~mask)
    return np.where(mask, 0.5 - inside, outside - 0.5).astype(np.float32)


def sample(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 image at (x, y)."""
    return cv2.remap(
        image,
        x.astype(np.float32).reshape(1, -1),
        y.astype(np.float32).reshape(1, -1),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).ravel()


def check_contours(table: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """Median distance to the true boundary, median |cos| tangent vs boundary normal.

    Median outward agreement.
    """
    phi = signed_distance(truth)
    distance = np.abs(sample(phi, table['x'], table['y']))
    smooth = cv2.GaussianBlur(phi, (0, 0), 1.5)
    gx, gy = (
        sample(cv2.Sobel(smooth, cv2.CV_32F, *d), table['x'], table['y']) for d in ((1, 0), (0, 1))
    )
    norm = np.hypot(gx, gy) + 1e-9
    across = np.abs(table['tx'] * gx + table['ty'] * gy) / norm  # tangent . boundary normal
    outward = (-table['ty'] * gx + table['tx'] * gy) / norm  # (-ty, tx) . outward normal
    return float(np.median(distance)), float(np.median(across)), float(np.median(outward))


# ------------------------------------------------------------- synthetic
def test_ellipse_contour_is_on_the_boundary_unit_tangent_counter_clockwise_on_screen():
    mask = np.zeros((200, 240), np.uint8)
    cv2.ellipse(mask, (120, 95), (70, 40), 30.0, 0, 360, 1, -1)
    mask = mask.astype(bool)
    _, regions = select_regions(mask, 10)
    table = occluding_contours([regions[0].outline], step=2.0, smoothing=2.0)
    assert table.dtype == CONTOUR_DTYPE and len(table) > 100
    np.testing.assert_allclose(np.hypot(table['tx'], table['ty']), 1.0, atol=1e-5)
    assert np.all(table['contour'] == 0)
    spacing = np.hypot(np.diff(table['x']), np.diff(table['y']))
    assert np.median(spacing) == pytest.approx(2.0, abs=0.1)
    distance, across, outward = check_contours(table, mask)
    assert distance < 0.3 and across < 0.1 and outward > 0.99
    x, y = table['x'].astype(float), table['y'].astype(float)
    assert (
        np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y) < 0
    )  # negative shoelace area (y down)


def test_degenerate_and_empty_outlines_give_no_error():
    assert len(occluding_contours([])) == 0 and occluding_contours([]).dtype == CONTOUR_DTYPE
    for outline in (
        np.array([[5, 5]]),
        np.array([[5, 5], [6, 5]]),
        np.array([[1, 1], [2, 1], [3, 1]]),
        np.array([[0, 0], [1, 0], [1, 1], [0, 1]]),
        np.zeros((0, 2), np.int32),
    ):
        table = occluding_contours([outline, np.array([[0, 0], [9, 0], [9, 9], [0, 9]])])
        assert np.all(np.isfinite(table['x'])) and np.all(np.isfinite(table['tx']))
        assert set(np.unique(table['contour'])) <= {0, 1}
    xy, t = smooth_closed_contour(np.array([[3, 3], [3, 3], [3, 3]]))
    assert len(xy) == 1 and np.all(t == 0)
    with pytest.raises(ValueError):
        occluding_contours([np.array([[0, 0], [4, 0], [4, 4]])], step=0.0)


def _rectangle_image(seed: int = 0):
    img = np.full((120, 160), 60, np.uint8)
    corners = cv2.boxPoints(((80, 60), (70, 36), 25.0))
    cv2.fillConvexPoly(
        img, np.round(corners * 16).astype(np.int32), 200, lineType=cv2.LINE_AA, shift=4
    )
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    noise = np.random.default_rng(seed).normal(0, 2, img.shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8), corners


def test_rotated_rectangle_gives_four_edge_lines_along_its_sides():
    img, corners = _rectangle_image()
    table = edge_lines(img, None, low=30, high=80, min_length=6, tolerance=1.5)
    assert table.dtype == EDGE_DTYPE and len(table) == 4
    assert np.all(table['magnitude'] > 0)
    sides = [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    matched = set()
    for line in table:
        p1, p2 = np.array([line['x1'], line['y1']]), np.array([line['x2'], line['y2']])
        for i, (a, b) in enumerate(sides):
            d = (b - a) / np.linalg.norm(b - a)
            n = np.array([-d[1], d[0]])
            if abs(np.dot(p1 - a, n)) < 1.5 and abs(np.dot(p2 - a, n)) < 1.5:
                angle = np.degrees(
                    np.arccos(min(abs(np.dot((p2 - p1) / np.linalg.norm(p2 - p1), d)), 1.0))
                )
                assert angle < 3.0
                assert np.linalg.norm(p2 - p1) > 0.8 * np.linalg.norm(b - a)
                matched.add(i)
    assert matched == {0, 1, 2, 3}


def test_edges_stay_in_the_box_and_flat_images_have_none():
    img, _ = _rectangle_image()
    box = (40, 20, 40, 30)
    table = edge_lines(img, box, margin=0)
    assert len(table) >= 1
    for name in ('x1', 'x2'):
        assert np.all((table[name] >= 39) & (table[name] <= 80))
    assert len(edge_lines(np.full((50, 60), 90, np.uint8))) == 0
    assert len(edge_lines(img, (10, 10, 1, 1), margin=0)) == 0
    assert merge_boxes([(0, 0, 10, 10), (5, 5, 10, 10), (50, 50, 5, 5)]) == [
        (0, 0, 15, 15),
        (50, 50, 5, 5),
    ]
    both = edge_lines_in_boxes(img, [(30, 20, 30, 30), (70, 40, 50, 50)])
    assert len(both) >= 2 and both['chain'].dtype == np.uint32


# ------------------------------------------------------------- pipeline
def test_edge_lines_of_a_frame_processed_without_them_are_those_processed_with_them():
    # a node whose edges gained a subscriber while it processed a frame adds them afterwards
    rng = np.random.default_rng(7)
    background = (
        cv2.GaussianBlur(rng.normal(110, 25, (240, 320)), (0, 0), 2).clip(0, 255).astype(np.uint8)
    )
    frame = background.copy()
    cv2.ellipse(frame, (160, 120), (30, 70), 0, 0, 360, 230, -1)
    with_lines, without = (
        ContourPipeline(segmenter='background', background_frames=2) for _ in '12'
    )
    for image in (background, background, frame):
        wanted = with_lines.process(image, edges=True)
        skipped = without.process(image, edges=False)
        assert len(skipped.edges) == 0
        assert np.array_equal(without.edge_lines(image, skipped), wanted.edges)
    assert len(wanted.edges) > 0  # the person's frame has lines; the warm-up frames none
    colour = np.repeat(frame[..., None], 3, axis=2)
    assert np.array_equal(without.edge_lines(colour, skipped), wanted.edges)


def test_pipeline_warms_up_resets_and_reports_every_stage():
    rng = np.random.default_rng(5)
    background = (
        cv2.GaussianBlur(rng.normal(110, 25, (240, 320)), (0, 0), 2).clip(0, 255).astype(np.uint8)
    )
    settings = PipelineSettings(segmenter='background', background_frames=3)
    pipeline = ContourPipeline(settings)
    for _ in range(3):
        result = pipeline.process(background)
        assert result.warming_up and len(result.contours) == 0 and result.box is None
    frame = background.copy()
    cv2.ellipse(frame, (160, 120), (30, 70), 0, 0, 360, 230, -1)
    result = pipeline.process(frame)
    assert not result.warming_up and set(result.timings) == set(ContourPipeline.STAGES)
    x, y, w, h = result.box
    assert abs(x - 130) <= 2 and abs(y - 50) <= 2 and abs(w - 61) <= 3 and abs(h - 141) <= 3
    assert result.contours.dtype == CONTOUR_DTYPE and len(result.contours) > 100
    assert result.edges.dtype == EDGE_DTYPE and len(result.edges) > 0
    assert pipeline.process(background).box is None  # the person left
    pipeline.reset()
    assert pipeline.process(frame).warming_up
    change = ContourPipeline(segmenter='change', threshold=12.0)
    assert change.process(background).warming_up
    assert change.process(frame).box is not None
    assert len(change.process(frame).contours) == 0  # nothing moved since
    with pytest.raises(ValueError):
        ContourPipeline(contour_step=0.0)


@pytest.fixture(scope='module')
def studio_frames(tmp_path_factory):
    """Cam -> (grey frames, true silhouettes, empty-studio frames) of a noisy studio-arm."""
    options = ImagingOptions()
    bag = tmp_path_factory.mktemp('arm') / 'bag'
    result = simulate('studio-arm', bag, frames=3, width=WIDTH, height=HEIGHT, options=options)
    body = load_studio_actor()
    scenario = make_scenario('studio-arm', body, WIDTH, HEIGHT, 3)
    q, _ = scenario.coordinates(np.arange(3) / scenario.frame_rate)
    poses = [body.forward_kinematics(qk) for qk in q]
    out = {}
    for cam in scenario.cameras:
        frames = [grey for _, grey in grey_images(bag, f'/{cam.name}/image_raw')]
        truth = [render(cam, R, o, body.semi_axes, body.lengths).label > 0 for R, o in poses]
        # the simulator's empty studio precedes the subject
        out[cam.name] = (frames[result.empty_frames :], truth, frames[: result.empty_frames])
    return out


def test_contours_of_simulated_frames_lie_on_the_true_silhouette(studio_frames):
    for name, (frames, truth, empty) in studio_frames.items():
        pipeline = ContourPipeline(
            segmenter='background', threshold=4.0, background_frames=len(empty), keep='all'
        )
        for e in empty:
            pipeline.process(e)
        for frame, t in zip(frames, truth):
            result = pipeline.process(frame)
            distance, across, outward = check_contours(result.contours, t)
            print(
                f'{name}: median distance {distance:.2f} px, |cos(tangent, normal)| {across:.3f}, '
                f'outward {outward:.3f}, {len(result.contours)} points, {len(result.edges)} edge '
                'lines'
            )
            assert distance <= 1.5 and across < 0.2 and outward > 0.9
            np.testing.assert_allclose(
                np.hypot(result.contours['tx'], result.contours['ty']), 1.0, atol=1e-5
            )
            assert len(result.edges) > 0 and np.all(result.edges['magnitude'] > 0)
