"""A round's width under a stereo matcher's window (laser._rim_free): real frames of the
simulated stereo camera, where the refit inside the rims once came out far off."""

from __future__ import annotations

from tests.test_stereo_shapes import _bench_frame


def test_a_band_refitted_inside_its_rims_does_not_narrow_pass_after_pass() -> None:
    """SGBM (block 5), the jar cap's 60 mm band seen from the front, trial 1 frame 4: each
    refit inside the rims held fewer samples within its bands than the last, the arc measured
    against the refit's own span passed the shortest-arc test on the third pass (25 px of 43,
    of 56 seen) and the band came out 23 mm wide. Against the span the samples show, the
    third arc is too short and the second refit stands."""
    view, result = _bench_frame(
        "jar_cap", 1, 4, suite="irregular", detail="front", kind="sgbm", block_size=5
    )
    assert result.shape == "cylinder"
    error_mm = 1000 * (result.grasp_width_m - view.truth.grasp_width_m)
    assert abs(error_mm) < 12.0, error_mm
