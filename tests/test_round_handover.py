"""The round rules' shared inputs (laser._seen_round): _decide works out the lines' samples,
the whole arc's fit's residuals on them and their view angles across its axis once a frame
and hands them to _rim_free, _silhouette_bound and _background_bound, which otherwise build
them each. Real frames of the simulated stereo camera where each rule trims the width."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lpc_core.perception.scans import cut_scan_lines


@pytest.mark.parametrize(
    ("trial", "frame", "matcher", "rule"),
    [
        # _rim_free refits inside the rims (test_stereo_shapes: the can pulled forward).
        (1, 1, {"kind": "sgbm", "block_size": 7}, 0),
        # _silhouette_bound bounds the width (the can before the table, SGBM 9).
        (0, 2, {"kind": "sgbm", "block_size": 9}, 1),
        # _background_bound bounds it (the can under BM 7).
        (0, 1, {"kind": "bm", "block_size": 7, "uniqueness": 5, "texture_threshold": 20}, 2),
    ],
)
def test_the_round_rules_give_the_same_on_the_inputs_handed_over(
    trial: int, frame: int, matcher: dict[str, object], rule: int
) -> None:
    """The 60 mm can upright: each rule gives the same to the bit whether it builds its
    inputs or is handed them (``rule``, the one that trims this frame, gives a width), on a
    trimmed solid that keeps the fit's axis (the view angles are the fit's); handed residuals
    that leave no sample on the round, that rule finds none: the handover is what it reads."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.laser import (
        LaserParams,
        _background_bound,
        _cylinder_candidate,
        _pixel_rad,
        _rim_free,
        _seen_round,
        _SeenRound,
        _silhouette_bound,
        analyse_lines,
    )
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(**matcher))  # type: ignore[arg-type]
    view = next(
        v
        for v in lv.views("functional", 2, 5, 0, names=["cylinder_upright"], sensor=sensor)
        if (v.trial, v.frame) == (trial, frame)
    )
    scan_lines = cut_scan_lines(view.depth, lv.INTRINSICS)
    lines = analyse_lines(scan_lines, seed=view.seq)
    params = LaserParams()
    clean = np.concatenate([ln.points.take(ln.run, axis=0) for ln in lines])
    full = _cylinder_candidate(lines, clean, params).solid
    assert full is not None
    pixel_rad = _pixel_rad(lines, params)
    seen = _seen_round(lines, full)
    narrower = replace(full, radius=0.9 * full.radius)

    def rules(handed: _SeenRound | None) -> tuple[object, ...]:
        return (
            _rim_free(lines, full, clean, params, pixel_rad, scan_lines, seen=handed),
            _silhouette_bound(lines, full, params, pixel_rad, scan_lines, handed),
            _background_bound(lines, narrower, full, params, pixel_rad, scan_lines, handed),
        )

    alone = rules(None)
    assert alone[rule] is not None, alone
    assert repr(rules(seen)) == repr(alone)
    # Handed residuals that put every sample a metre off the fit, no rule finds the round.
    off = seen._replace(residuals=np.ones_like(seen.residuals))
    assert rules(off)[rule] is None
