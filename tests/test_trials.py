"""The simulated trial loop: whole trials through the real step functions on rendered frames,
the render window, the grasp physics, and the paper's statistics."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import numpy as np
import pytest

from lpc_core.perception.cloud import CloudParams, crop_points
from lpc_core.perception.scans import cut_scan_lines
from lpc_core.sim import scene as sc
from lpc_core.trials import (
    PAPER_SEQUENCE,
    TrialConfig,
    TrialOutcome,
    TrialSpec,
    _Attempt,
    _Camera,
    _envelop,
    fresh_carry,
    friedman,
    make_person,
    median_iqr,
    run_block,
    run_trial,
    user_block_medians,
    wilcoxon_p,
)

# Fast settings: a 10 Hz camera, two objects.
FAST = TrialConfig(camera_hz=10.0)


def spec(index: int, practice: int = 1, seed: int = 0) -> TrialSpec:
    name, azimuth, elevation = PAPER_SEQUENCE[index]
    return TrialSpec(
        user=0,
        block=0,
        index=index,
        object_name=name,
        azimuth_deg=azimuth,
        elevation_deg=elevation,
        practice=practice,
        seed=seed,
    )


@pytest.fixture(scope="module")
def laser_block() -> tuple[list[TrialOutcome], list[tuple[str, object, int]]]:
    """One user, one block of the first two objects, laser with feedback, recorded."""
    person = make_person(FAST, 0, seed=0)
    recorded: list[tuple[str, object, int]] = []
    outcomes = run_block(
        FAST,
        person,
        block=0,
        seed=0,
        sequence=PAPER_SEQUENCE[:2],
        sink_for=lambda s: (
            (lambda key, m, t: recorded.append((key, m, t))) if s.index == 0 else None
        ),
    )
    return outcomes, recorded


def test_run_block_completes_the_pick_and_place_trials(laser_block) -> None:
    outcomes, _ = laser_block
    assert [o.object for o in outcomes] == [PAPER_SEQUENCE[0][0], PAPER_SEQUENCE[1][0]]
    for o in outcomes:
        assert o.completed, o
        # Reach, aim, a 10-frame window at 7 Hz, trigger, pre-shape, take over, grasp, carry
        # 0.5 m, release: several seconds, well under the trial limit.
        assert 6.0 < o.tat_s < 30.0, o
        assert o.triggers >= 1 and o.take_overs >= 1 and o.preshapes >= 1
        assert o.first_ready_s is not None and o.first_ready_s < o.trigger_s < o.take_over_s
        assert o.reconstructions > 10
        assert o.frames >= o.reconstructions
    assert [o.index for o in outcomes] == [0, 1]


def test_run_trial_records_the_topics_of_a_live_session(laser_block) -> None:
    _, recorded = laser_block
    keys = Counter(key for key, _, _ in recorded)
    for key in (
        "lpc/scans",
        "lpc/reconstruction",
        "lpc/grasp/target",
        "lpc/aim/cue",
        "lpc/tactors/command",
        "lpc/emg",
        "lpc/controller/state",
        "lpc/prosthesis/command",
        "lpc/prosthesis/state",
    ):
        assert keys[key] > 0, key
    assert "lpc/camera/depth" not in keys  # only with record_depth
    times = [t for _, _, t in recorded]
    assert times == sorted(times)  # log times never go back
    # EMG and the hand at 100 Hz; the camera at 10 Hz while vision matters.
    assert keys["lpc/emg"] == keys["lpc/prosthesis/state"]
    assert keys["lpc/scans"] < keys["lpc/emg"] / 5
    states = [m.state for k, m, _ in recorded if k == "lpc/controller/state"]
    for state in ("idle", "aiming", "ready", "preshaping", "direct"):
        assert state in states, state
    reconstructions = [m for k, m, _ in recorded if k == "lpc/reconstruction"]
    assert all(m.compute_ms == pytest.approx(138.0) for m in reconstructions)


def test_run_trial_is_reproducible_from_the_seed() -> None:
    """A short trial (it times out while aiming): same seed, same trial; another seed differs."""
    config = dataclasses.replace(FAST, max_trial_s=1.5, max_attempts=1)
    person = make_person(config, 1, seed=5)

    def once(seed: int) -> list[tuple[str, int]]:
        recorded: list[tuple[str, int]] = []
        outcome, _ = run_trial(
            config, person, spec(0, seed=seed), fresh_carry(config),
            lambda key, m, t: recorded.append((key, hash(bytes(str(m), "utf8")))),
        )  # fmt: skip
        assert outcome.failures == ("timeout",) and not outcome.completed
        return recorded

    a, b, c = once(1), once(1), once(2)
    assert a == b
    assert a != c


def test_camera_window_renders_every_pixel_the_method_reads() -> None:
    """Rendering only the window gives the same scan lines and the same cloud crop as the full
    frame (no noise, so that only the geometry counts)."""
    obj = sc.functional_objects()["cuboid_tilt_right"]
    world = sc.Scene((obj,), sc.table())
    exact = sc.NoiseModel.exact()
    for method in ("laser", "cloud"):
        config = TrialConfig(method=method)
        camera = _Camera.for_config(config)
        for dx in (-0.04, 0.0, 0.03):
            pose = sc.aim_pose(obj, 0.19) @ sc.make_pose(None, (dx, 0.01, 0.0))
            full = sc.render_depth(world, config.intrinsics, pose, np.random.default_rng(0), exact)
            window = camera.render(world, pose, np.random.default_rng(0), exact)
            if method == "laser":
                a = cut_scan_lines(full, config.intrinsics)
                b = cut_scan_lines(window, config.intrinsics)
                for pa, pb in zip(a.points, b.points, strict=True):
                    np.testing.assert_array_equal(pa, pb)
                assert a.capture_count == b.capture_count
            else:
                params = CloudParams()
                np.testing.assert_array_equal(
                    crop_points(full, config.intrinsics, params),
                    crop_points(window, config.intrinsics, params),
                )
        v0, v1, u0, u1 = camera.window
        fraction = (v1 - v0) * (u1 - u0) / (config.intrinsics.width * config.intrinsics.height)
        assert fraction < (0.25 if method == "laser" else 0.95)


def test_envelop_collides_when_the_hand_is_too_narrow_and_slips_when_turned() -> None:
    obj = sc.functional_objects()["cylinder_upright"]  # 60 mm
    pose = sc.aim_pose(obj, 0.19)
    hand = fresh_carry(FAST).hand
    view = obj.truth(pose)  # the axis is vertical in the image: 90 degrees from the grasp

    def attempt(view_: sc.ObjectTruth) -> _Attempt:
        return _Attempt(take_over_view=view_)

    narrow = dataclasses.replace(hand, aperture_mm=50.0)
    failure, _ = _envelop(FAST, obj, attempt(view), narrow)
    assert failure.startswith("collision")
    turned = attempt(view)
    failure, held = _envelop(FAST, obj, turned, dataclasses.replace(hand, aperture_mm=75.0))
    assert failure == "" and held.object_mm == pytest.approx(60.0) and turned.slip
    aligned = attempt(dataclasses.replace(view, wrist_angle_rad=math.radians(10.0)))
    failure, held = _envelop(FAST, obj, aligned, dataclasses.replace(hand, aperture_mm=75.0))
    assert failure == "" and not aligned.slip


def test_trial_config_rejects_bad_settings() -> None:
    with pytest.raises(ValueError, match="camera_hz"):
        TrialConfig(camera_hz=30.0)
    with pytest.raises(ValueError, match="method"):
        TrialConfig(method="lidar")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="recon_period_s"):
        TrialConfig(recon_period_s=0.0)
    assert TrialConfig(method="cloud").period_s == pytest.approx(0.075)
    assert TrialConfig(feedback=False).condition == "laser-feedback-off"


# --------------------------------------------------------------------------- statistics


def outcome(user: int, block: int, index: int, tat: float | None) -> TrialOutcome:
    return TrialOutcome(
        user=user, block=block, index=index, object="x", shape="sphere",
        completed=tat is not None, tat_s=tat, attempts=1,
    )  # fmt: skip


def test_user_block_medians_takes_each_person_s_median_over_completed_trials() -> None:
    outcomes = [outcome(0, 0, i, t) for i, t in enumerate([10.0, 12.0, 30.0, None])]
    outcomes += [outcome(1, 1, 0, 8.0)]
    m = user_block_medians(outcomes, [0, 1], 2)
    assert m[0, 0] == 12.0 and math.isnan(m[0, 1]) and math.isnan(m[1, 0]) and m[1, 1] == 8.0
    assert median_iqr(np.array([1.0, 2.0, 3.0, 4.0, 5.0, np.nan])) == (3.0, 2.0)
    assert all(math.isnan(v) for v in median_iqr(np.array([np.nan])))


def test_friedman_finds_a_consistent_decrease_across_blocks() -> None:
    rng = np.random.default_rng(0)
    users, blocks = 10, 5
    learning = 16.0 - 1.0 * np.arange(blocks)  # every user a second faster per block
    medians = learning + rng.normal(0.0, 0.5, (users, blocks)) + rng.normal(0, 2, (users, 1))
    test = friedman(medians)
    assert test is not None and test.n == users
    assert test.p < 0.001
    first_last = next(p for p in test.pairs if p[:2] == (0, blocks - 1))
    assert first_last[2] < 0.01 and first_last[3] == pytest.approx(min(first_last[2] * 10, 1.0))
    flat = friedman(rng.normal(10.0, 1.0, (users, blocks)))
    assert flat is not None and flat.p > 0.01
    assert friedman(medians[:, :2]) is None  # fewer than three blocks


def test_wilcoxon_p_pairs_users_and_handles_ties_and_gaps() -> None:
    a = np.array([10.0, 12.0, 11.0, 14.0, 13.0, 12.5, 15.0, 11.5, 13.5, 12.2])
    p, n = wilcoxon_p(a + 3.0 + 0.1 * np.arange(10), a)
    assert n == 10 and p < 0.01
    assert wilcoxon_p(a, a) == (1.0, 10)
    b = a.copy()
    b[:9] = np.nan
    p, n = wilcoxon_p(a, b)
    assert n == 1 and math.isnan(p)
