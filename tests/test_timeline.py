"""Tests for lpc_core.sim.timeline: the scripted demo session as a pure function of time."""

from __future__ import annotations

import numpy as np
import pytest

from lpc_core.perception.intrinsics import D435_424X240
from lpc_core.perception.scans import cut_scan_lines
from lpc_core.sim.scene import NoiseModel, Scene, functional_objects, render_depth
from lpc_core.sim.timeline import SimTimeline, TimelineStop, default_timeline

INTR = D435_424X240


def test_timeline_is_deterministic() -> None:
    a, b = default_timeline(seed=3), default_timeline(seed=3)
    for t in (0.0, 0.7, 2.2, 4.3, 13.1):
        sa, sb = a.at(t), b.at(t)
        assert np.array_equal(sa.camera_pose, sb.camera_pose)
        assert sa.phase == sb.phase and sa.stop_index == sb.stop_index
        assert sa.target == sb.target
    assert not np.array_equal(a.at(2.0).camera_pose, default_timeline(seed=4).at(2.0).camera_pose)


def test_timeline_repeats_forever() -> None:
    tl = default_timeline()
    for t in (0.3, 3.0, 7.9):
        now, later = tl.at(t), tl.at(t + 2 * tl.period_s)
        assert later.stop_index == now.stop_index and later.phase == now.phase
        assert np.allclose(later.camera_pose, now.camera_pose, atol=1e-9)


def test_timeline_first_ten_seconds_show_aiming_on_target_and_a_complete_visit() -> None:
    tl = default_timeline()
    samples = [tl.at(k / 90.0) for k in range(900)]
    phases = [s.phase for s in samples]
    stops = [s.stop_index for s in samples]
    assert {"approach", "on_target", "transit"} <= set(phases)
    assert stops[0] == 0 and max(stops) >= 1
    # Stop 0 runs through approach, on target and transit before stop 1 starts.
    first = [p for p, i in zip(phases, stops, strict=True) if i == 0]
    assert first[0] == "approach" and "on_target" in first and first[-1] == "transit"
    shapes = [tl.stops[i].obj.shape for i in range(3)]
    assert shapes == ["sphere", "cylinder", "cuboid"]
    # The hand starts off target and is on it by the end of the approach.
    assert not samples[0].target.pierced
    assert tl.at(tl.approach_s - 1e-3).target.pierced
    assert all(s.target is None for s in samples if s.phase == "transit")


@pytest.mark.parametrize("index", range(10))
def test_timeline_keeps_aimed_object_inside_capture_volume(index: int) -> None:
    tl = default_timeline()
    for frac in (0.0, 0.5, 0.99):
        t = index * tl.stop_s + tl.approach_s + frac * tl.dwell_s
        sample = tl.at(t)
        assert sample.phase == "on_target" and sample.stop_index == index
        truth = sample.target
        assert truth is not None and truth.pierced
        assert 0.15 <= truth.pierce_depth_m <= 0.25
        # The object alone (no table) gives every scan line enough points in the volume.
        depth = render_depth(
            Scene(sample.scene.objects, None),
            INTR,
            sample.camera_pose,
            np.random.default_rng(index),
            NoiseModel(),
        )
        lines = cut_scan_lines(depth, INTR)
        assert lines.ok, f"{truth.name}: {lines.counts}"


def test_timeline_tremor_is_small_on_target() -> None:
    tl = default_timeline()
    t0 = tl.approach_s + 0.1
    ts = np.linspace(t0, t0 + 2.0, 60)
    pos = np.array([tl.at(t).camera_pose[:3, 3] for t in ts])
    spread = np.linalg.norm(pos - pos.mean(axis=0), axis=1)
    assert 1e-4 < spread.max() < 3e-3  # moving, but by millimetres


def test_timeline_custom_stops_and_no_table() -> None:
    cat = functional_objects()
    tl = SimTimeline(
        stops=(TimelineStop(obj=cat["cylinder_upright"], elevation_deg=10.0),),
        support=None,
        approach_s=1.0,
        dwell_s=2.0,
        transit_s=0.5,
    )
    assert tl.period_s == pytest.approx(3.5)
    sample = tl.at(1.5)
    assert sample.scene.support is None and sample.phase == "on_target"
    assert sample.target.name == "cylinder_upright"
    assert default_timeline(with_table=False).at(0.0).scene.support is None
    assert default_timeline(objects=["cuboid_lying"]).stops[0].obj.name == "cuboid_lying"


def test_timeline_invalid_input_raises_value_error() -> None:
    with pytest.raises(ValueError, match="t_s"):
        default_timeline().at(-1.0)
    with pytest.raises(ValueError, match="stops"):
        SimTimeline(stops=())
    with pytest.raises(ValueError, match="dwell_s"):
        SimTimeline(stops=default_timeline().stops, dwell_s=0.0)
    with pytest.raises(ValueError, match="objects"):
        default_timeline(objects=["teapot"])
