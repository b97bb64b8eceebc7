"""`memo-ros benchmark contours` on a few frames: every case with and without edge lines.

The report has every figure with sane values (no timing asserted).
"""

from __future__ import annotations

from memo_ros.tools.benchmarks.contours import (
    ENCODINGS,
    SEGMENTERS,
    STAGES,
    print_contour_benchmark,
    run_contour_benchmark,
)


def test_each_case_is_timed_with_and_without_edge_lines(tmp_path, capsys):
    report = run_contour_benchmark(repeat=1, frames=3, workdir=tmp_path)
    cases = {(c['encoding'], c['segmenter'], c['edges']): c for c in report['cases']}
    assert set(cases) == {
        (e, s, edges) for e in ENCODINGS for s in SEGMENTERS for edges in (True, False)
    }
    for (encoding, segmenter, edges), case in cases.items():
        assert case['frames'] > 0 and set(case['median_ms']) == set(STAGES) | {'total'}
        other = cases[(encoding, segmenter, not edges)]
        assert case['frames'] == other['frames']  # the same frames, taken in turn
    print_contour_benchmark(report)
    out = capsys.readouterr().out
    assert out.count('without edge lines') == len(ENCODINGS) * len(SEGMENTERS)
    assert out.count('of the time of whole frames') == len(ENCODINGS) * 2  # windowed, per edges
