"""laser._runs: where a model's inliers along a scan line's segment break into runs."""

from __future__ import annotations

import numpy as np

from lpc_core.perception.laser import LaserParams, _runs

PARAMS = LaserParams()  # max_outlier_run 3, segment_gap_m 8 mm, run_gap_m 15 mm


def _segment() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """40 samples 1 mm apart along s with an 11 mm jump between samples 29 and 30; outliers:
    two at 5-6 (a short gap), five in front of the model at 12-16 (a bump), five behind it at
    22-26 (a long gap) and one at 29 (across the jump)."""
    s = np.arange(40) * 0.001 + np.where(np.arange(40) >= 30, 0.010, 0.0)
    points = np.column_stack([s, np.zeros(40), np.full(40, 0.3)])
    inliers = np.ones(40, bool)
    inliers[[5, 6, 12, 13, 14, 15, 16, 22, 23, 24, 25, 26, 29]] = False
    front = np.zeros(40, bool)
    front[12:17] = True
    return inliers, points, front


def test_runs_end_at_long_gaps_and_jumps_but_not_over_a_bump_in_front() -> None:
    inliers, points, front = _segment()
    runs = [r.tolist() for r in _runs(inliers, points, PARAMS, front)]
    assert runs == [
        [0, 1, 2, 3, 4, 7, 8, 9, 10, 11, 17, 18, 19, 20, 21],
        [27, 28],
        list(range(30, 40)),
    ]


def test_runs_without_a_front_end_at_every_long_gap() -> None:
    inliers, points, _ = _segment()
    runs = [r.tolist() for r in _runs(inliers, points, PARAMS)]
    assert runs == [
        [0, 1, 2, 3, 4, 7, 8, 9, 10, 11],
        [17, 18, 19, 20, 21],
        [27, 28],
        list(range(30, 40)),
    ]


def test_the_front_mask_is_made_only_where_a_run_would_end() -> None:
    _, points, front = _segment()
    asked = []

    def lazily() -> np.ndarray:
        asked.append(True)
        return front

    short_gap = np.ones(40, bool)
    short_gap[[5, 6]] = False
    assert [r.tolist() for r in _runs(short_gap, points, PARAMS, lazily)] == [
        [i for i in range(40) if i not in (5, 6)]
    ]
    assert asked == []
    short_gap[29] = False  # 28 -> 30 spans the 11 mm jump: a run would end there
    assert len(_runs(short_gap, points, PARAMS, lazily)) == 2
    assert asked == [True]
