"""The real four-camera Pose2Sim demo, on a few frames.

Import, segment without a clean background, measure the body, track, and score by silhouette IoU
(no DDS; the live graph runs it in scripts/demo_pose2sim.sh).
"""

import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from memo_ros.core.evaluation.silhouette_score import silhouette_iou
from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.render import render_labels
from memo_ros.core.multiview.body_estimation import (
    estimate_body,
    measure_height,
    silhouette_from_contours,
)
from memo_ros.core.multiview.tracking import ArticulatedTracker
from memo_ros.core.vision.background import background_from_frames
from memo_ros.core.vision.contours import ContourPipeline
from memo_ros.core.vision.tracked_region import body_region
from memo_ros.ros.images import image_message_to_frame

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(
    os.environ.get('POSE2SIM_DEMO', ROOT.parent / 'shared' / 'data' / 'pose2sim_demo_single')
)
CLI_ENTRY = 'import sys; from memo_ros.tools.cli import main; sys.exit(main())'
BACKGROUND_FRAMES = 50  # of the 100, spread over the recording (as background_frames does)
TRACKED_FRAMES = 24
pytestmark = pytest.mark.skipif(
    not (DATA / 'Calib.qca.txt').is_file(), reason=f'no Pose2Sim demo in {DATA}'
)


@pytest.fixture(scope='module')
def demo(tmp_path_factory):
    """Return the demo imported at scale 0.25 (bgr8), its studio, and every camera's frames."""
    out = tmp_path_factory.mktemp('pose2sim') / 'demo'
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run(
        [
            sys.executable,
            '-c',
            CLI_ENTRY,
            'import',
            'videos',
            *[str(DATA / f'cam0{k}.mp4') for k in range(1, 5)],
            '--calibration',
            str(DATA / 'Calib.qca.txt'),
            '--out',
            str(out),
            '--scale',
            '0.25',
            '--encoding',
            'bgr8',
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    from memo_ros.ros.bagio import read_messages

    studio = Studio.load(out.with_name(out.name + '.yaml'))
    frames = {
        c: [image_message_to_frame(m.message) for m in read_messages(out, [f'/{c}/image_raw'])]
        for c in studio.camera_names
    }
    return studio, frames


@pytest.fixture(scope='module')
def backgrounds(demo):
    """Each camera's background learnt from the recording, as by contour_node's background_bag."""
    studio, frames = demo
    return {
        name: background_from_frames(frames[name], BACKGROUND_FRAMES)
        for name in studio.camera_names
    }


def pipelines(backgrounds) -> dict[str, ContourPipeline]:
    """Return the demo's contour pipelines (scripts/demo_pose2sim.sh's settings).

    Starting from the backgrounds.
    """
    out = {}
    for name, model in backgrounds.items():
        pipeline = ContourPipeline(
            segmenter='sequence', threshold=12.0, keep='tracked', learn_margin=3
        )
        pipeline.segmenter.method.set_model(model.copy())
        out[name] = pipeline
    return out


def test_the_four_silhouettes_agree_on_one_standing_person_of_plausible_size(demo, backgrounds):
    studio, frames = demo
    segmented = pipelines(backgrounds)
    first = {c: segmented[c].process(frames[c][0]) for c in studio.camera_names}
    masks = [
        silhouette_from_contours(first[c.name].contours, c.width, c.height) for c in studio.cameras
    ]
    for mask in masks:  # someone is segmented in every camera, not the whole image
        assert 0.02 < mask.mean() < 0.25
    height, hulls = measure_height([(studio.cameras, masks)])
    # each camera was segmented on its own: a ghost or a background person in one of them would not
    # survive
    # the carving by the three others; what does is one person standing on the treadmill (z = 0)
    assert 1.60 < height < 1.85
    assert -0.15 < hulls[0].bottom < 0.05


def test_tracking_the_first_frames_overlaps_the_segmented_person(demo, backgrounds):
    studio, frames = demo
    segmented = pipelines(backgrounds)
    cameras = studio.cameras
    tracker = None
    body = None
    ious = {c.name: [] for c in cameras}
    previous = None
    for k in range(TRACKED_FRAMES):
        results = {}
        for cam in cameras:
            pipeline = segmented[cam.name]
            image = frames[cam.name][k]
            pipeline.set_roi(
                None
                if previous is None
                else body_region(
                    cam, *previous, body.semi_axes, body.lengths, image.shape[:2], 6.0
                )
            )
            results[cam.name] = pipeline.process(image)
        if tracker is None:
            masks = [
                silhouette_from_contours(results[c.name].contours, c.width, c.height)
                for c in cameras
            ]
            body, height = estimate_body([(cameras, masks)], studio.body)
            assert 1.60 < height < 1.85
            tracker = ArticulatedTracker(body, cameras)
        step = tracker.step(int(k * 1e9 / 60), {c: r.contours for c, r in results.items()})
        assert step.status == 'tracking', step.reason  # no frame lost
        previous = (step.rotations, step.origins)
        for cam in cameras:
            model = (
                render_labels(
                    cam, step.rotations, step.origins, body.semi_axes, body.lengths
                ).label
                > 0
            )
            ious[cam.name].append(silhouette_iou(model, results[cam.name].mask))
    means = {c: float(np.mean(v)) for c, v in ious.items()}
    # measured 2026-11-21 over these 24 frames (the start-up, where the standing posture the track
    # starts
    # from still has to reach the dancer's): cam01 0.44, cam02 0.53, cam03 0.57, cam04 0.56; over
    # the whole
    # sequence with the background of all 100 frames 0.64 - 0.72 (README).  A model beside the
    # person, or
    # lost, scores under 0.2.
    assert min(means.values()) > 0.38, means
    assert np.mean(list(means.values())) > 0.48, means
