"""The contour pipeline, configured as the simulator's studio file configures contour_node.

On its bags.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.render import render
from memo_ros.core.geometry.rotations import quat_to_matrix
from memo_ros.core.simulation.imaging import ImagingOptions
from memo_ros.core.vision.contours import ContourPipeline
from memo_ros.nodes.contour_node import pipeline_settings
from memo_ros.ros.bagio import grey_images, read_messages, stamp_to_ns
from memo_ros.tools.simulate import TRUTH_POSES, simulate

CASES = [('studio-arm', 4), ('street-walk', 20)]


def _truth_poses(bag):
    poses = {}
    for m in read_messages(bag, [TRUTH_POSES]):
        p = m.message.poses
        origins = np.array([[x.position.x, x.position.y, x.position.z] for x in p])
        quats = np.array(
            [[x.orientation.x, x.orientation.y, x.orientation.z, x.orientation.w] for x in p]
        )
        poses[stamp_to_ns(m.message.header.stamp)] = (quat_to_matrix(quats), origins)
    return poses


@pytest.mark.parametrize(
    'noise, target', [(0.0, 0.9), (3.0, 0.8)], ids=['noise-free', 'default-noise']
)
@pytest.mark.parametrize('scenario, frames', CASES, ids=[c[0] for c in CASES])
def test_silhouettes_and_contours_match_the_rendered_truth(
    tmp_path, scenario, frames, noise, target
):
    result = simulate(
        scenario, tmp_path / 'bag', frames=frames, options=ImagingOptions(noise=noise)
    )
    studio = Studio.load(result.studio)
    settings = pipeline_settings(studio.node_parameters['contour_node'])
    truth = _truth_poses(result.bag)
    body = studio.body
    for cam in studio.cameras:
        pipeline = ContourPipeline(settings)
        scored = 0
        for stamp, grey in grey_images(result.bag, f'/{cam.name}/image_raw'):
            out = pipeline.process(grey)
            if stamp not in truth:  # the empty studio: learning, then nobody
                assert len(out.contours) == 0
                continue
            if out.warming_up:  # the street learns while the pedestrian walks
                continue
            silhouette = render(cam, *truth[stamp], body.semi_axes, body.lengths).label > 0
            iou = (out.mask & silhouette).sum() / (out.mask | silhouette).sum()
            assert iou >= target, (cam.name, stamp, iou)
            boundary = silhouette.astype(np.uint8) - cv2.erode(
                silhouette.astype(np.uint8), np.ones((3, 3))
            )
            distance = cv2.distanceTransform((1 - boundary).astype(np.uint8), cv2.DIST_L2, 5)
            x = np.clip(np.round(out.contours['x']).astype(int), 0, cam.width - 1)
            y = np.clip(np.round(out.contours['y']).astype(int), 0, cam.height - 1)
            assert np.median(distance[y, x]) <= 1.5, (cam.name, stamp)
            scored += 1
        assert scored >= 4, cam.name


def test_an_empty_scene_after_learning_gives_an_empty_contour_set(tmp_path):
    result = simulate('studio-arm', tmp_path / 'bag', frames=1, width=320, height=240)
    studio = Studio.load(result.studio)
    pipeline = ContourPipeline(pipeline_settings(studio.node_parameters['contour_node']))
    frames = grey_images(result.bag, '/cam_front/image_raw')
    for _, grey in frames[: result.empty_frames]:
        pipeline.process(grey)
    again = pipeline.process(frames[0][1])  # the empty studio once more, learnt now
    assert not again.warming_up and len(again.contours) == 0 and again.box is None
    assert len(pipeline.process(frames[-1][1]).contours) > 0
