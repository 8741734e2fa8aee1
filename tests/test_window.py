"""The 10-frame window: majority shape, medians, axial wrap-around, the reconstructed flag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lpc_core.perception.reconstruction import Reconstruction
from lpc_core.perception.window import WindowParams, WindowState, axial_median, window_step

FRAME_NS = 11_111_111  # 90 fps


def _rec(
    shape: str, width_mm: float | None = None, angle_deg: float | None = None
) -> Reconstruction:
    return Reconstruction(
        shape=shape,  # type: ignore[arg-type]
        grasp_width_m=None if width_mm is None else width_mm / 1000,
        wrist_angle_rad=None if angle_deg is None else math.radians(angle_deg),
    )


def _run(recs: list[Reconstruction], state: WindowState | None = None, start: int = 0):
    state = state or WindowState()
    result = None
    for k, rec in enumerate(recs):
        state, result = window_step(state, rec, start + k, (start + k) * FRAME_NS)
    assert result is not None
    return state, result


def test_window_step_medians_over_majority_shape() -> None:
    widths = [60, 61, 59, 62, 58, 60, 200, 61, 60, 59]  # one wild frame
    recs = [_rec("cylinder", w, 10.0) for w in widths]
    recs[3] = _rec("sphere", 90.0)
    _, result = _run(recs)
    assert result.shape == "cylinder"
    assert result.grasp_width_mm == pytest.approx(60.0)
    assert result.wrist_angle_deg == pytest.approx(10.0)
    assert result.frames == 10 and result.agreement == pytest.approx(0.9)
    assert result.reconstructed


def test_window_step_angle_median_wraps_at_plus_minus_90() -> None:
    angles = [89.0, -89.0, 88.0, -88.5, 89.5, -89.5, 87.0, -87.0, 89.0, -88.0]
    _, result = _run([_rec("cuboid", 40.0, a) for a in angles])
    assert result.wrist_angle_deg is not None
    assert abs(abs(result.wrist_angle_deg) - 90.0) < 1.5


def test_window_step_not_reconstructed_until_window_full() -> None:
    state = WindowState()
    for k in range(9):
        state, result = window_step(state, _rec("sphere", 40.0), k, k * FRAME_NS)
        assert not result.reconstructed
        assert result.shape == "sphere" and result.wrist_angle_rad is None
    state, result = window_step(state, _rec("sphere", 40.0), 9, 9 * FRAME_NS)
    assert result.reconstructed and result.frames == 10


def test_window_step_needs_enough_agreeing_frames() -> None:
    shapes = ["cuboid"] * 6 + ["cylinder"] * 2 + ["none"] * 2
    _, result = _run([_rec(s, 40.0, 0.0) if s != "none" else _rec("none") for s in shapes])
    assert result.shape == "cuboid"
    assert not result.reconstructed  # 6 < min_agree = 7


def test_window_step_majority_none_gives_no_target() -> None:
    recs = [_rec("none")] * 6 + [_rec("sphere", 40.0)] * 4
    _, result = _run(recs)
    assert result.shape == "none"
    assert result.grasp_width_m is None and not result.reconstructed


def test_window_step_tie_goes_to_most_recent_shape() -> None:
    _, result = _run([_rec("sphere", 40.0)] * 5 + [_rec("cylinder", 40.0, 0.0)] * 5)
    assert result.shape == "cylinder"


def test_window_step_restarts_after_pause_or_seq_going_back() -> None:
    state, _ = _run([_rec("sphere", 40.0)] * 10)
    _, result = window_step(state, _rec("cuboid", 30.0, 0.0), 10, 10 * FRAME_NS + 10**9)
    assert result.frames == 1 and result.shape == "cuboid"
    _, result = window_step(state, _rec("cuboid", 30.0, 0.0), 3, 11 * FRAME_NS)
    assert result.frames == 1


def test_window_step_keeps_only_last_size_frames() -> None:
    state, result = _run([_rec("sphere", 40.0)] * 10 + [_rec("cylinder", 50.0, 0.0)] * 7)
    assert len(state.entries) == 10
    assert result.shape == "cylinder" and result.reconstructed


def test_axial_median_simple_and_wrapped() -> None:
    assert math.degrees(axial_median(np.radians([10, 20, 30]))) == pytest.approx(20.0)
    # On the axis circle -85 lies 10 degrees past +85: the median of 80, 85, 95 is 85.
    assert math.degrees(axial_median(np.radians([80, -85, 85]))) == pytest.approx(85.0)
    with pytest.raises(ValueError, match="angles"):
        axial_median(np.array([]))


def test_window_params_reject_bad_values() -> None:
    with pytest.raises(ValueError, match="min_agree"):
        WindowParams(size=5, min_agree=6)
    with pytest.raises(ValueError, match="size"):
        WindowParams(size=0, min_agree=1)


def test_median_is_numpys_to_the_bit() -> None:
    """``reconstruction.median`` replaces ``np.median`` in the window and the fattening
    estimate, whose outputs are compared byte for byte in the golden replays."""
    import math
    import random

    from lpc_core.perception.reconstruction import median

    rng = random.Random(7)
    pool = [-0.0, 0.0, 1.5, -2.25, math.inf, -math.inf]
    cases = [[-0.0], [-0.0, -0.0], [0.0, -0.0, -0.0], [1.0, -1.0]]
    cases += [[rng.choice([*pool, rng.uniform(-5, 5)]) for _ in range(rng.randint(1, 9))]
              for _ in range(20_000)]  # fmt: skip
    with np.errstate(invalid="ignore"):  # inf - inf in numpy's mean of the middle two
        for values in cases:
            want, got = float(np.median(values)), median(values)
            assert (math.isnan(want) and math.isnan(got)) or (
                want == got and math.copysign(1, want) == math.copysign(1, got)
            ), values
