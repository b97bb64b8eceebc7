"""Per-frame cost of the contour pipeline (segmentation, cleanup, contours, edge lines) at 640x480.

A simulated studio-walk is written as mono8 and as bgr8 bags; every cam_front
frame goes through :class:`memo_ros.core.vision.contours.ContourPipeline` exactly as
the contour node runs it (``image_to_array`` + ``to_grey8``, then the
pipeline), once per segmenter, on one OpenCV thread, and twice: with the edge
lines (a node whose edges someone subscribes to, the walker) and without (the
studio graph, ``edges: auto`` with no subscriber).  The two pipelines take each
frame in turn, so a change in the machine's load hits both alike.  Figures are
wall-clock milliseconds per frame: median and 90th percentile, total and per stage.
"""

from __future__ import annotations

from pathlib import Path
import tempfile
import time

import cv2
import numpy as np

from memo_ros.core.simulation.imaging import ImagingOptions
from memo_ros.core.vision.contours import ContourPipeline
from memo_ros.core.vision.encodings import image_to_array, to_grey8

SCENARIO = 'studio-walk'
CAMERA = 'cam_front'
SIZE = (640, 480)
TIMED_FRAMES = 50
ENCODINGS = ('mono8', 'bgr8')
BACKGROUND = {'segmenter': 'background', 'threshold': 4.0, 'background_frames': 10, 'keep': 'all'}
SEGMENTERS = {  # segmenter -> settings it runs with (the recommended defaults)
    'background': BACKGROUND,
    'change': {'segmenter': 'change', 'threshold': 12.0, 'keep': 'largest'},
    # the background segmenter in the box around the previous person, as a live contour_node
    # runs it (window_margin, full_frame_every: its defaults)
    'windowed': {**BACKGROUND, 'window_margin': 32, 'full_frame_every': 15},
}
STAGES = ('convert', 'segment', 'cleanup', 'contours', 'edges')


def _frames(bag: Path) -> list[tuple]:
    """Return the camera's image messages as tuples.

    Each is (encoding, height, width, step, data, is_bigendian).
    """
    from memo_ros.ros.bagio import read_messages

    frames = []
    for m in read_messages(bag, [f'/{CAMERA}/image_raw']):
        msg = m.message
        frames.append(
            (msg.encoding, msg.height, msg.width, msg.step, bytes(msg.data), msg.is_bigendian)
        )
    return frames


def _time_pipeline(
    frames: list[tuple], settings: dict, warmup: int, repeat: int
) -> dict[bool, dict[str, np.ndarray]]:
    """Milliseconds per stage and in total for every timed frame, with and without edge lines.

    Keyed by whether the edge lines were computed; ``repeat`` passes, history reset between.
    """
    clock = time.perf_counter
    times = {
        with_edges: {stage: [] for stage in STAGES + ('total',)} for with_edges in (True, False)
    }
    pipelines = {with_edges: ContourPipeline(**settings) for with_edges in times}
    for _ in range(repeat):
        for pipeline in pipelines.values():
            pipeline.reset()
        for index, (encoding, height, width, step, data, big) in enumerate(frames):
            for with_edges, pipeline in pipelines.items():
                t0 = clock()
                grey = to_grey8(image_to_array(encoding, height, width, step, data, big), encoding)
                t1 = clock()
                result = pipeline.process(grey, edges=with_edges)
                t2 = clock()
                if index < warmup or result.warming_up:
                    continue
                out = times[with_edges]
                out['convert'].append(t1 - t0)
                for stage in STAGES[1:]:
                    out[stage].append(result.timings[stage])
                out['total'].append(t2 - t0)
    return {
        with_edges: {k: 1000.0 * np.asarray(v) for k, v in ms.items()}
        for with_edges, ms in times.items()
    }


def run_contour_benchmark(
    repeat: int = 1, frames: int = TIMED_FRAMES, workdir: Path | None = None
) -> dict:
    """Time the pipeline per encoding and segmenter on a simulated 640x480 studio-walk.

    a JSON-ready dict.
    """
    from memo_ros.tools.simulate import simulate

    if repeat < 1:
        raise ValueError('repeat must be at least 1')
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core, as a contour node per camera would get
    try:
        with tempfile.TemporaryDirectory(dir=workdir) as tmp:
            warmup = max(s.get('background_frames', 1) for s in SEGMENTERS.values())
            total_frames = warmup + frames
            bags = {}
            for encoding in ENCODINGS:
                bag = Path(tmp) / f'walk_{encoding}'
                simulate(
                    SCENARIO,
                    bag,
                    frames=total_frames,
                    width=SIZE[0],
                    height=SIZE[1],
                    options=ImagingOptions(),
                    encoding=encoding,
                )
                bags[encoding] = _frames(bag)
            cases = []
            for encoding, frame_list in bags.items():
                for name, settings in SEGMENTERS.items():
                    timed = _time_pipeline(frame_list, settings, warmup, repeat)
                    for with_edges, ms in timed.items():
                        cases.append(
                            {
                                'encoding': encoding,
                                'segmenter': name,
                                'edges': with_edges,
                                'frames': int(len(ms['total'])),
                                'median_ms': {k: float(np.median(v)) for k, v in ms.items()},
                                'p90_ms': {k: float(np.percentile(v, 90)) for k, v in ms.items()},
                            }
                        )
    finally:
        cv2.setNumThreads(threads)
    return {
        'scenario': SCENARIO,
        'camera': CAMERA,
        'size': list(SIZE),
        'opencv_threads': 1,
        'repeat': repeat,
        'settings': SEGMENTERS,
        'cases': cases,
        'target_ms': 8.0,
    }


def print_contour_benchmark(report: dict) -> None:
    """Return the benchmark as a table.

    One row per encoding x segmenter, median (p90) ms per stage.
    """
    width, height = report['size']
    print(
        f'contour pipeline, {report["scenario"]} {report["camera"]} {width}x{height}, '
        f'{report["opencv_threads"]} OpenCV thread, target {report["target_ms"]:.0f} ms/frame'
    )
    columns = STAGES + ('total',)
    print(
        f'{"encoding":8} {"segmenter":10} {"edges":5} {"frames":>6} '
        + ' '.join(f'{c:>14}' for c in columns)
    )
    for case in report['cases']:
        cells = ' '.join(
            f'{case["median_ms"][c]:6.2f} ({case["p90_ms"][c]:5.2f})' for c in columns
        )
        edges = 'on' if case['edges'] else 'off'
        print(f'{case["encoding"]:8} {case["segmenter"]:10} {edges:5} {case["frames"]:6d} {cells}')
    windowed = report['settings']['windowed']
    print(
        'figures: median (p90) milliseconds per frame; edges off: no edge lines computed; '
        f'windowed: the background segmenter within {windowed["window_margin"]} px of the '
        f"previous frame's person, the whole frame every {windowed['full_frame_every']}th frame "
        '(contour_node window_margin, full_frame_every)'
    )
    cases = {(c['encoding'], c['segmenter'], c['edges']): c for c in report['cases']}
    for (encoding, segmenter, edges), c in cases.items():
        if not edges:
            with_edges = cases[(encoding, segmenter, True)]['median_ms']['total']
            print(
                f'{encoding} {segmenter}: without edge lines '
                f'{c["median_ms"]["total"] / with_edges:.2f} of the time with them '
                f'({with_edges - c["median_ms"]["total"]:.2f} ms less at the median)'
            )
    for (encoding, segmenter, edges), c in cases.items():
        whole = cases.get((encoding, 'background', edges))
        if segmenter == 'windowed' and whole:
            ratio = c['median_ms']['total'] / whole['median_ms']['total']
            print(
                f'{encoding} windowed, edges {"on" if edges else "off"}: {ratio:.2f} of the time '
                f'of whole frames ({whole["median_ms"]["total"] - c["median_ms"]["total"]:.2f} ms '
                'less at the median)'
            )


def main(argv: list[str] | None = None) -> int:
    """``python -m memo_ros.tools.benchmarks.contours [REPEAT]``: run and print."""
    import sys

    args = sys.argv[1:] if argv is None else argv
    print_contour_benchmark(run_contour_benchmark(int(args[0]) if args else 1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
