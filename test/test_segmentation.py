"""Change detection (Rohr eq. 1), binary cleanup, regions, the segmenters on simulated frames."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from memo_ros.core.geometry.body import load_studio_actor
from memo_ros.core.geometry.render import render
from memo_ros.core.simulation.imaging import ImagingOptions
from memo_ros.core.simulation.scenarios import STUDIO_EMPTY_FRAMES, make_scenario
from memo_ros.core.vision.change_detection import (
    ChangeDetector,
    Workspace,
    change_mask,
    change_statistic,
    change_statistic_reference,
    design_matrix,
    detect_changes,
)
from memo_ros.core.vision.cleanup import cleanup
from memo_ros.core.vision.segmentation import (
    BackgroundSegmenter,
    Segmenter,
    carve_background_channels,
    select_regions,
)
from memo_ros.ros.bagio import grey_images
from memo_ros.tools.simulate import simulate

WIDTH, HEIGHT = 640, 480
DEFAULT_NOISE = ImagingOptions().noise  # the simulator's default sensor noise
STREET_LEARN = 15  # street: background learnt while the pedestrian walks through
STREET_FRAMES = STREET_LEARN + 6
ARM_FRAMES = 4
EMPTY_FRAMES = STUDIO_EMPTY_FRAMES  # studio: background learnt from the simulator's empty studio


# --------------------------------------------------------------- eq. (1)
def _smooth_noisy_pair(shape=(20, 24), seed=3):
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.normal(120, 40, shape), (0, 0), 2.0) + rng.normal(0, 3, shape)
    moved = base + rng.normal(0, 3, shape)
    moved[6:13, 8:17] += 25.0  # a systematic change
    moved[2:5, 18:22] -= 12.0
    return np.clip(base, 0, 255).round().astype(np.uint8), np.clip(moved, 0, 255).round().astype(
        np.uint8
    )


def test_separable_eq1_equals_the_explicit_least_squares_fit():
    frame_j, frame_k = _smooth_noisy_pair()
    fast = change_statistic(frame_k, frame_j)
    slow = change_statistic_reference(frame_k, frame_j)
    np.testing.assert_allclose(fast, slow, atol=1e-3)  # borders included: reflect-101 in both
    for threshold in (2.0, 4.0, 8.0, 12.0):
        ref_mask = slow > threshold
        assert ref_mask.any() and not ref_mask.all()
        safe = np.abs(slow - threshold) > 1e-3  # float32 vs float64 exactly at T
        np.testing.assert_array_equal(
            change_mask(frame_k, frame_j, threshold)[safe], ref_mask[safe]
        )
        assert np.array_equal(change_mask(frame_k, frame_j, threshold), ref_mask) or not safe.all()


def test_design_matrix_and_projection_span():
    X = design_matrix()
    assert X.shape == (25, 6) and np.linalg.matrix_rank(X) == 6
    # a quadratic difference is reproduced exactly: statistic = rms of the quadratic over the
    # window
    y, x = np.mgrid[0:15, 0:15].astype(float)
    quad = 0.3 * x * x - 0.2 * x * y + 2 * y + 5
    stat = change_statistic(quad.astype(np.float32), np.zeros_like(quad, np.float32))
    window = quad[5:10, 5:10]
    assert stat[7, 7] == pytest.approx(np.sqrt(np.mean(window**2)), rel=1e-4)


def test_noise_floor_and_change_detector_use_the_previous_frame_only():
    rng = np.random.default_rng(0)
    a = np.clip(rng.normal(128, 3, (120, 160)), 0, 255).astype(np.uint8)
    b = np.clip(rng.normal(128, 3, (120, 160)), 0, 255).astype(np.uint8)
    result = detect_changes(a, b, 1.0, workspace=Workspace())
    assert result.sigma == pytest.approx(3 * np.sqrt(2), rel=0.2)
    assert result.threshold > 1.0 and result.mask.sum() < 5  # pure noise: (almost) nothing flagged
    detector = ChangeDetector(threshold=10.0)
    assert detector.update(a) is None  # first frame primes
    c = a.copy()
    c[40:60, 50:90] = 250
    assert detector.update(c)[50, 70] and not detector.update(c)[50, 70]  # c vs a, then c vs c
    detector.reset()
    assert detector.update(a) is None


# --------------------------------------------------------------- cleanup
def test_cleanup_deletes_sparse_points_marks_dense_gaps_and_fills_holes():
    mask = np.zeros((60, 80), bool)
    mask[10:40, 10:50] = True
    mask[20:25, 20:30] = False  # a hole
    mask[10:40, 30] = False  # a one-pixel crack, dense neighbours on both sides
    mask[50, 70] = True  # isolated point
    mask[5, 60:75] = True  # a thin line: two neighbours each
    out = cleanup(mask, delete_below=3, fill_above=5, max_iterations=10)
    assert out.dtype == bool and out.shape == mask.shape
    assert out[
        11:39, 10:50
    ].all()  # crack and hole filled (its two ends stay notches: 5 neighbours)
    assert not out[10, 30] and out[10:40, 10:50].sum() == 30 * 40 - 2
    assert not out[50, 70] and not out[5, 60:75].any()
    no_fill = cleanup(mask, fill_holes=False)
    assert not no_fill[22, 25] and no_fill[22, 15]  # the hole's inside has no flagged neighbours
    assert not cleanup(np.zeros((10, 10), bool)).any()


def test_select_regions_keeps_largest_or_all_with_boxes_and_outlines():
    mask = np.zeros((100, 120), bool)
    mask[10:60, 10:40] = True  # 1500 px
    mask[70:90, 80:110] = True  # 600 px
    mask[5:8, 100:103] = True  # 9 px
    kept, regions = select_regions(mask, min_area=50, keep='largest')
    assert len(regions) == 1 and regions[0].box == (10, 10, 30, 50) and regions[0].area == 1500
    assert kept.sum() == 1500
    kept, regions = select_regions(mask, min_area=50, keep='all')
    assert [r.area for r in regions] == [1500, 600] and kept.sum() == 2100
    outline = regions[1].outline
    assert outline[:, 0].min() == 80 and outline[:, 0].max() == 109 and outline[:, 1].min() == 70
    assert select_regions(np.zeros((5, 5), bool))[1] == []
    with pytest.raises(ValueError):
        select_regions(mask, keep='biggest')


def test_unknown_segmenter_is_refused():
    with pytest.raises(ValueError, match='unknown segmenter'):
        Segmenter(segmenter='magic')


# ----------------------------------------------------- simulated scenarios
def _grey_frames(bag, topic):
    return [grey for _, grey in grey_images(bag, topic)]


def _scenario_frames(tmp_path_factory, name: str, frames: int, noise: float) -> dict:
    """Camera -> (frames, true silhouettes, empty-studio frames) of a simulated scenario."""
    options = ImagingOptions(noise=noise)
    bag = tmp_path_factory.mktemp(f'{name}_{noise}') / 'bag'
    result = simulate(name, bag, frames=frames, width=WIDTH, height=HEIGHT, options=options)
    body = load_studio_actor()
    scenario = make_scenario(name, body, WIDTH, HEIGHT, frames)
    q, _ = scenario.coordinates(np.arange(frames) / scenario.frame_rate)
    poses = [body.forward_kinematics(qk) for qk in q]
    out = {}
    for cam in scenario.cameras:
        images = _grey_frames(bag, f'/{cam.name}/image_raw')
        truth = [render(cam, R, o, body.semi_axes, body.lengths).label > 0 for R, o in poses]
        # the simulator's empty studio, seen before the subject steps in (none in the street)
        empty = images[: result.empty_frames]
        out[cam.name] = (images[result.empty_frames :], truth, empty)
    return out


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope='module', params=[0.0, DEFAULT_NOISE], ids=['noise-free', 'default-noise'])
def studio_arm(request, tmp_path_factory):
    return request.param, _scenario_frames(
        tmp_path_factory, 'studio-arm', ARM_FRAMES, request.param
    )


@pytest.fixture(scope='module', params=[0.0, DEFAULT_NOISE], ids=['noise-free', 'default-noise'])
def street(request, tmp_path_factory):
    return request.param, _scenario_frames(
        tmp_path_factory, 'street-walk', STREET_FRAMES, request.param
    )


def test_studio_arm_background_segmenter_silhouettes(studio_arm):
    noise, cameras = studio_arm
    target = 0.9 if noise == 0 else 0.8
    assert set(cameras) == {'cam_front', 'cam_side', 'cam_top'}
    for name, (images, truth, empty) in cameras.items():
        segmenter = Segmenter(
            segmenter='background', threshold=4.0, background_frames=EMPTY_FRAMES, keep='all'
        )
        assert all(segmenter.process(e).warming_up for e in empty)
        scores = [iou(segmenter.process(image).mask, t) for image, t in zip(images, truth)]
        print(f'studio-arm noise={noise} {name} background IoU', np.round(scores, 3))
        assert min(scores) >= target, (name, scores)


def test_street_background_segmenter_learnt_while_the_pedestrian_passes(street):
    noise, cameras = street
    target = 0.9 if noise == 0 else 0.8
    images, truth, _ = cameras['cam_street']
    segmenter = Segmenter(segmenter='background', threshold=4.0, background_frames=STREET_LEARN)
    scores = []
    for k, (image, t) in enumerate(zip(images, truth)):
        result = segmenter.process(image)
        assert result.warming_up == (k < STREET_LEARN)
        if not result.warming_up:
            scores.append(iou(result.mask, t))
            x, y, w, h = result.box
            ys, xs = np.nonzero(t)
            assert (
                abs(y - ys.min()) <= 3 and abs(y + h - 1 - ys.max()) <= 3
            )  # head and sole rows (Rohr §4.2)
    print(f'street noise={noise} background IoU', np.round(scores, 3))
    assert min(scores) >= target, scores


def test_change_segmenter_finds_the_pedestrian_not_the_silhouette(street):
    # eq. (1) against the previous frame flags what moved: the pedestrian's moving edges and the
    # background just uncovered, not the uniform inside of the clothes; Rohr uses it for the
    # enclosing rectangle.  Its silhouette IoU is low by nature (about 0.4 here), reported, not a
    # target.
    noise, cameras = street
    images, truth, _ = cameras['cam_street']
    segmenter = Segmenter(segmenter='change', threshold=12.0, keep='all', min_area=50)
    assert segmenter.process(images[0]).warming_up
    scores, inside = [], []
    for image, t in zip(images[1:], truth[1:]):
        result = segmenter.process(image)
        scores.append(iou(result.mask, t))
        x, y, w, h = result.box
        inside.append(t[y : y + h, x : x + w].sum() / t.sum())
    print(
        f'street noise={noise} change IoU',
        np.round(scores, 3),
        'person inside box',
        np.round(inside, 3),
    )
    assert np.median(scores) > 0.3 and np.median(inside) > 0.9


def test_change_segmenter_on_the_studio_arm_sees_only_the_arm(studio_arm):
    noise, cameras = studio_arm
    for name, (images, truth, _) in cameras.items():
        segmenter = Segmenter(segmenter='change', threshold=12.0, keep='all')
        segmenter.process(images[0])
        scores = [iou(segmenter.process(image).mask, t) for image, t in zip(images[1:], truth[1:])]
        print(f'studio-arm noise={noise} {name} change IoU', np.round(scores, 3))
        assert max(scores) < 0.5  # a standing subject is not a change: background segmenter there


def _arm_beside_trunk(
    noise: float, slit: int, seed: int = 4
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Background, a frame with a trunk and an arm ``slit`` px apart (open at the bottom).

    The true mask.
    """
    rng = np.random.default_rng(seed)
    background = cv2.GaussianBlur(rng.normal(120, 25, (120, 160)), (0, 0), 3).clip(0, 255)
    truth = np.zeros((120, 160), bool)
    truth[20:100, 40:80] = True  # trunk
    truth[20:70, 80 + slit : 92 + slit] = True  # arm hanging beside it
    truth[20:26, 80 : 80 + slit] = True  # shoulder joins them at the top
    frame = np.where(truth, 185.0, background)

    def noisy(img: np.ndarray) -> np.ndarray:
        return (img + rng.normal(0, noise, img.shape)).clip(0, 255).round().astype(np.uint8)

    return noisy(background), noisy(frame), truth


@pytest.mark.parametrize('slit', [1, 2, 3, 4])
def test_noise_free_frames_keep_the_slit_between_arm_and_trunk(slit):
    background, frame, truth = _arm_beside_trunk(0.0, slit)
    segmenter = Segmenter(segmenter='background', threshold=1.0, background_frames=1, keep='all')
    segmenter.process(background)
    mask = segmenter.process(frame).mask
    assert mask[30:68, 80 : 80 + slit].sum() == 0  # the slit stays open down its whole length
    assert (mask ^ truth).sum() <= 4  # and nothing else moves (the slit's closed top end)
    closed = Segmenter(
        segmenter='background', threshold=1.0, background_frames=1, keep='all', exact_noise=0.0
    )
    closed.process(background)
    assert (
        closed.process(frame).mask[30:68, 80 : 80 + slit].all()
    )  # the old behaviour: cleanup closes it


def test_carving_stops_at_the_person_and_is_off_under_noise():
    background, frame, truth = _arm_beside_trunk(3.0, 2)
    segmenter = Segmenter(segmenter='background', threshold=1.0, background_frames=1, keep='all')
    segmenter.process(background)
    mask = segmenter.process(frame).mask
    assert mask[30:68, 80:82].all()  # noise: per-pixel tests unsafe, slit closed as before
    assert (mask & truth).sum() >= 0.99 * truth.sum()
    # an unchanged patch enclosed by the person is not background reaching in
    enclosed = np.zeros((20, 20), bool)
    enclosed[2:18, 2:18] = True
    difference = np.where(enclosed, 50.0, 0.0).astype(np.float32)
    difference[8:12, 8:12] = 0.0
    carved = carve_background_channels(enclosed, difference, 0.5)
    assert carved[8:12, 8:12].all() and carved.sum() == enclosed.sum()
    difference[8:12, 2:12] = 0.0  # now joined to the outside
    assert carve_background_channels(enclosed, difference, 0.5)[8:12, 8:12].sum() == 0


def test_background_segmenter_follows_a_global_lighting_change():
    rng = np.random.default_rng(1)
    background = (
        cv2.GaussianBlur(rng.normal(120, 30, (120, 160)), (0, 0), 3).clip(0, 255).astype(np.uint8)
    )
    segmenter = BackgroundSegmenter(threshold=4.0, learn_frames=1)
    assert segmenter.segment(background) is None
    brighter = (background * 1.08).clip(0, 255).astype(np.uint8)
    brighter[40:80, 60:100] = 250
    result = segmenter.segment(brighter)
    assert segmenter.gain == pytest.approx(1.08, abs=0.01)
    assert result.mask[50:70, 70:90].all() and result.mask.sum() < 1.3 * 40 * 40


@pytest.fixture(scope='module', params=[0.0, DEFAULT_NOISE], ids=['noise-free', 'default-noise'])
def studio_arm_longer(request, tmp_path_factory):
    return request.param, _scenario_frames(tmp_path_factory, 'studio-arm', 24, request.param)


def test_a_window_around_the_person_segments_as_the_whole_frame_does(studio_arm_longer):
    """window_margin: the box around the previous person, grown; the whole frame now and then.

    The same person as whole frames give, in a window most of the time. Only the noise level
    differs (measured on the last whole frame, within 1 % of the frame's own), and so the
    threshold: at default noise a hole between the waving arm and the trunk can close in one
    and not the other (IoU 0.935 in one frame of 24 in cam_front), as it does from one whole
    frame to the next.
    """
    noise, cameras = studio_arm_longer
    for name, (images, _, empty) in cameras.items():
        whole = Segmenter(segmenter='background', background_frames=EMPTY_FRAMES, keep='all')
        windowed = Segmenter(
            segmenter='background',
            background_frames=EMPTY_FRAMES,
            keep='all',
            window_margin=32,
            full_frame_every=5,
        )
        for e in empty:
            whole.process(e), windowed.process(e)
        scores, windows = [], 0
        for image in images:
            a, b = whole.process(image), windowed.process(image)
            windows += windowed._window is not None
            scores.append(iou(a.mask, b.mask))
        print(f'studio-arm noise={noise} {name} windowed against whole IoU', np.round(scores, 3))
        assert min(scores) >= 0.9 and np.mean(scores) >= 0.99, (name, scores)
        assert windows >= 0.7 * len(images), (name, windows)


def test_a_person_outside_the_window_is_found_by_the_next_whole_frame_or_at_its_edge():
    """A second person far from the window shows within full_frame_every frames.

    One who moves past the window's edge makes the frame a whole one at once.
    """
    empty = np.full((120, 160), 100, np.uint8)
    segmenter = Segmenter(
        segmenter='background',
        background_frames=2,
        keep='all',
        min_area=20,
        window_margin=6,
        full_frame_every=4,
    )
    segmenter.process(empty), segmenter.process(empty)

    def frame(*boxes):
        image = empty.copy()
        for x, y in boxes:
            image[y : y + 30, x : x + 12] = 180
        return image

    counts = []
    for k in range(8):
        result = segmenter.process(frame((20, 40), (120, 40)) if k >= 2 else frame((20, 40)))
        counts.append(len(result.regions))
    assert counts[:2] == [1, 1]
    assert 2 in counts[2:6], counts  # the whole frame within full_frame_every frames
    assert counts[-1] == 2, counts  # and kept from then on: both are in the window
    jumped = segmenter.process(frame((20, 40), (120, 40), (70, 85)))
    assert len(jumped.regions) == 3  # past the window's edge: the whole frame at once
