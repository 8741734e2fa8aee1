"""The aim step: geometric cases of the cue, hysteresis, two objects, readiness."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

import numpy as np
import pytest
import zenoh

from lpc_core.control import aim
from lpc_core.control.aim import (
    AimParams,
    AimState,
    aim_step,
    capture_points,
    cluster_points,
    convex_hull,
    guide,
    hull_distance,
    tactor_placement,
    tactor_shares,
)
from schemas import (
    ControllerState,
    GraspTarget,
    ProsthesisState,
    ScanLine,
    ScanLines,
    TactorCommand,
    decode,
    encode,
    from_wire,
    to_wire,
)
from tests.conftest import spawn_service, wait_for

Z = 0.200  # depth of the test objects, inside the 150-250 mm capture volume
T0 = 1_700_000_000_000_000_000


def patch(x0: float, x1: float, y0: float, y1: float, step: float = 0.001) -> np.ndarray:
    """A flat rectangle of points at depth Z, corners included (mm-spaced grid)."""
    xs = np.linspace(x0, x1, round((x1 - x0) / step) + 1)
    ys = np.linspace(y0, y1, round((y1 - y0) / step) + 1)
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, Z)])


def ray(theta_deg: float, r0: float, r1: float, step: float = 0.001) -> np.ndarray:
    """Points of one scan line between radii r0 and r1 along direction theta."""
    r = np.arange(r0, r1 + step / 2, step)
    t = math.radians(theta_deg)
    return np.column_stack([r * math.cos(t), r * math.sin(t), np.full(r.size, Z)])


def scans(*lines: np.ndarray, t_ns: int = T0, seq: int = 1) -> ScanLines:
    return ScanLines(
        seq=seq,
        t_ns=t_ns,
        frame_seq=seq,
        lines=[
            ScanLine(angle_deg=45.0 * i, points=to_wire(p.astype(np.float32)))
            for i, p in enumerate(lines)
        ],
    )


def target(reconstructed: bool = True, t_ns: int = T0) -> GraspTarget:
    return GraspTarget(seq=1, t_ns=t_ns, frame_seq=1, shape="cylinder", reconstructed=reconstructed)


@pytest.mark.parametrize(
    ("points", "tactor", "theta_deg"),
    [
        (patch(0.030, 0.040, -0.005, 0.005), 0, 0.0),  # object to the right: move right
        (patch(-0.005, 0.005, 0.030, 0.040), 1, 90.0),  # below (y down): move down
        (patch(-0.040, -0.030, -0.005, 0.005), 2, 180.0),  # left
        (patch(-0.005, 0.005, -0.040, -0.030), 3, -90.0),  # above
    ],
)
def test_guide_each_direction_drives_one_tactor(
    points: np.ndarray, tactor: int, theta_deg: float
) -> None:
    g = guide(points, AimParams())
    # Nearest hull point 30 mm away: rho = 30 / 100, amplitude 1 - rho on one tactor only.
    assert g.state == "guiding"
    assert g.rho == pytest.approx(0.30, abs=1e-6)
    assert math.degrees(g.theta_rad) == pytest.approx(theta_deg, abs=1e-6)
    expected = np.zeros(4)
    expected[tactor] = 0.70
    np.testing.assert_allclose(g.amplitudes, expected, atol=1e-6)


def test_guide_diagonal_shares_equally() -> None:
    # Nearest corner (20, 20) mm: d = 28.28 mm at 45 deg, half the amplitude on each neighbour.
    g = guide(patch(0.020, 0.030, 0.020, 0.030), AimParams())
    rho = math.hypot(0.020, 0.020) / 0.100
    assert g.rho == pytest.approx(rho, abs=1e-6)
    np.testing.assert_allclose(g.amplitudes, [(1 - rho) / 2, (1 - rho) / 2, 0, 0], atol=1e-6)


def test_guide_thirty_degrees_shares_linearly() -> None:
    # One scan line hits an object from 30 mm outward at 30 deg: shares 2/3 and 1/3.
    g = guide(ray(30.0, 0.030, 0.045), AimParams())
    assert g.rho == pytest.approx(0.30, abs=1e-6)
    np.testing.assert_allclose(g.amplitudes, [0.7 * 2 / 3, 0.7 / 3, 0, 0], atol=1e-6)


def test_guide_inside_hull_is_on_target_with_all_tactors() -> None:
    g = guide(patch(-0.010, 0.020, -0.015, 0.010), AimParams())
    assert g.state == "on_target"
    assert g.signed_distance_m == pytest.approx(-0.010, abs=1e-9)  # nearest edge x = -10 mm
    assert g.amplitudes == (1.0, 1.0, 1.0, 1.0)


def test_guide_hysteresis_holds_on_target_near_the_edge() -> None:
    params = AimParams(hysteresis_m=0.002)
    just_outside = patch(0.001, 0.030, -0.010, 0.010)  # the axis 1 mm outside the hull
    assert guide(just_outside, params, was_on_target=False).state == "guiding"
    assert guide(just_outside, params, was_on_target=True).state == "on_target"
    outside = patch(0.003, 0.030, -0.010, 0.010)  # beyond the hysteresis band
    assert guide(outside, params, was_on_target=True).state == "guiding"


def test_guide_two_objects_side_by_side_not_taken_for_one() -> None:
    # Their joint hull contains the axis: the paper's method would say "on target".
    points = np.concatenate(
        [patch(-0.040, -0.015, -0.005, 0.005), patch(0.015, 0.040, -0.005, 0.005)]
    )
    g = guide(points, AimParams())
    assert g.state == "guiding"
    assert g.objects == 2
    assert g.rho == pytest.approx(0.15, abs=1e-6)
    assert math.degrees(g.theta_rad) % 180.0 == pytest.approx(0.0, abs=1e-6)


def test_guide_two_objects_cue_leads_to_one_not_the_gap() -> None:
    # Right and below: the merged hull's nearest point lies on the diagonal between them,
    # 7.07 mm away at 45 deg. The cue must point at one object, 15 mm away.
    points = np.concatenate(
        [patch(0.015, 0.040, -0.005, 0.005), patch(-0.005, 0.005, 0.015, 0.040)]
    )
    g = guide(points, AimParams())
    assert g.objects == 2
    assert g.rho == pytest.approx(0.15, abs=1e-6)
    assert math.degrees(g.theta_rad) in (pytest.approx(0.0, abs=1e-6), pytest.approx(90.0))
    assert sorted(g.amplitudes) == pytest.approx([0, 0, 0, 0.85], abs=1e-6)


def test_guide_keeps_the_chosen_object_of_two_at_equal_distance() -> None:
    left = patch(-0.040, -0.015, -0.005, 0.005)
    right = patch(0.015, 0.040, -0.005, 0.005)
    points = np.concatenate([right, left])
    for side in (left, right):
        chosen = tuple(side[:, :2].mean(axis=0))
        g = guide(points, AimParams(), chosen_xy=chosen)
        assert g.chosen_xy == pytest.approx(chosen, abs=1e-9)


def test_guide_objects_at_different_depths_are_separate() -> None:
    # Overlapping in the image, 40 mm apart in depth: two objects.
    near = patch(0.010, 0.030, -0.005, 0.005)
    far = patch(0.020, 0.040, -0.005, 0.005) + np.array([0, 0, 0.040])
    assert guide(np.concatenate([near, far]), AimParams()).objects == 2


def test_guide_sets_the_table_aside_and_leads_to_the_object_on_it() -> None:
    """A 30 mm ball 30 mm right of the axis, on a table spanning the capture volume at
    Z + 30 mm (the scan lines see both): the cue leads to the ball, not onto the table under
    the axis; without the table removal, ball and table are one object around the axis."""
    table = patch(-0.05, 0.05, -0.05, 0.05, step=0.004) + np.array([0, 0, 0.030])
    u, v = np.meshgrid(np.linspace(-1, 1, 15), np.linspace(-1, 1, 15))
    inside = u**2 + v**2 <= 1
    ball = np.column_stack(
        [
            0.030 + 0.015 * u[inside],
            0.015 * v[inside],
            Z + 0.015 - 0.015 * np.sqrt(1 - u[inside] ** 2 - v[inside] ** 2),
        ]
    )
    # The ball hides the table behind it.
    hidden = np.hypot(table[:, 0] - 0.030, table[:, 1]) < 0.016
    points = np.concatenate([table[~hidden], ball])
    g = guide(points, AimParams())
    assert g.state == "guiding" and g.objects == 1
    assert math.degrees(g.theta_rad) == pytest.approx(0.0, abs=1.0)
    assert g.signed_distance_m == pytest.approx(0.015, abs=0.002)
    assert guide(points, AimParams(remove_support=False)).state == "on_target"


def test_guide_nothing_in_view_switches_all_off() -> None:
    params = AimParams()
    assert guide(np.empty((0, 3)), params).amplitudes == (0.0,) * 4
    assert guide(patch(0.0, 0.002, 0.0, 0.002), params).state == "nothing"  # 9 points < 10
    beyond = capture_points([patch(-0.01, 0.01, -0.01, 0.01) + np.array([0, 0, 0.2])], params)
    assert len(beyond) == 0  # at z = 400 mm, outside the capture volume


def test_guide_noisy_scan_line_recovers_direction() -> None:
    rng = np.random.default_rng(6)
    points = ray(-60.0, 0.025, 0.045)
    points += rng.normal(0.0, 0.0003, points.shape)  # 0.3 mm, the D435's noise at 200 mm
    g = guide(points, AimParams())
    assert math.degrees(g.theta_rad) == pytest.approx(-60.0, abs=2.0)
    assert g.rho == pytest.approx(0.25, abs=0.01)


def test_convex_hull_degenerate_and_counter_clockwise() -> None:
    assert convex_hull(np.array([[0.01, 0.02]] * 3)).shape == (1, 2)
    segment = convex_hull(ray(45.0, 0.01, 0.03)[:, :2])
    assert segment.shape == (2, 2)
    square = convex_hull(patch(-0.01, 0.01, -0.01, 0.01)[:, :2])
    assert square.shape == (4, 2)
    x, y = square.T
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0  # positive area: CCW


@pytest.mark.parametrize("seed", range(6))
def test_convex_hull_matches_qhull(seed: int) -> None:
    """The same vertices, counter-clockwise, as scipy's Qhull: on noisy blobs, and on points
    lying on lines through the origin, as projected scan lines do."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(seed)
    blob = rng.normal([0.01, -0.02], 0.01, (rng.integers(3, 400), 2))
    lines = np.concatenate(
        [ray(a, rng.uniform(0.0, 0.02), rng.uniform(0.03, 0.06))[:, :2] for a in (0, 45, 90, 135)]
    )
    lines += rng.normal(0.0, 1e-5, lines.shape)
    for points in (blob, lines, np.concatenate([blob, lines])):
        hull = convex_hull(points)
        expected = points[ConvexHull(points).vertices]
        assert sorted(map(tuple, hull)) == sorted(map(tuple, expected))
        start = int(np.flatnonzero((expected == hull[0]).all(axis=1))[0])
        assert np.array_equal(hull, np.roll(expected, -start, axis=0))  # same cyclic order


@pytest.mark.parametrize("seed", range(8))
def test_convex_hull_filter_keeps_every_vertex_of_projected_scan_lines(seed: int) -> None:
    """The Akl-Toussaint filter only drops points that cannot be vertices: the hull equals
    the monotone chain of all the points, on scan lines as the scans service sends them
    (float32, exactly on the axes and diagonals: many exact ties) with repeated points."""
    rng = np.random.default_rng(seed)
    lines = []
    for angle in (0, 45, 90, 135):
        r = rng.uniform(-0.05, 0.05, int(rng.integers(5, 80))).astype(np.float32)
        c, s = round(math.cos(math.radians(angle))), round(math.sin(math.radians(angle)))
        lines.append(np.column_stack([r * c if c else 0 * r, r * s if s else 0 * r]))
    points = np.concatenate(lines).astype(float)
    points = np.concatenate([points, points[rng.integers(0, len(points), 10)]])
    points = points[rng.permutation(len(points))]
    expected = aim._monotone_chain(points.tolist())
    assert len(expected) >= 3  # the four lines span an area
    assert convex_hull(points).tolist() == [list(p) for p in expected]


def test_convex_hull_collinear_gives_the_far_ends() -> None:
    points = np.concatenate([ray(135.0, 0.0, 0.04)[:, :2], ray(-45.0, 0.001, 0.02)[:, :2]])
    hull = convex_hull(points[np.random.default_rng(1).permutation(len(points))])
    assert hull.shape == (2, 2)
    assert sorted(np.hypot(*hull.T)) == pytest.approx([0.02, 0.04])


def test_hull_distance_point_segment_polygon() -> None:
    assert hull_distance(np.array([[0.03, 0.04]]))[0] == pytest.approx(0.05)
    d, q = hull_distance(np.array([[0.02, -0.01], [0.02, 0.01]]))
    assert d == pytest.approx(0.02) and q == pytest.approx([0.02, 0.0])
    d, _ = hull_distance(convex_hull(patch(-0.01, 0.03, -0.02, 0.02)[:, :2]))
    assert d == pytest.approx(-0.01)


def test_tactor_placement_left_arm_mirrors_and_rotation_turns() -> None:
    down = math.pi / 2
    right_arm = tactor_shares(down, tactor_placement("right"))
    left_arm = tactor_shares(down, tactor_placement("left"))
    turned = tactor_shares(down, tactor_placement("right", rotation_deg=90.0))
    assert np.argmax(right_arm) == 1
    assert np.argmax(left_arm) == 3
    assert np.argmax(turned) == 0
    with pytest.raises(ValueError, match="arm"):
        tactor_placement("middle")  # type: ignore[arg-type]


def test_aim_params_reject_bad_values() -> None:
    with pytest.raises(ValueError, match="width_m"):
        AimParams(width_m=0.0)
    with pytest.raises(ValueError, match="tactor_angles_rad"):
        AimParams(tactor_angles_rad=(0.0, 1.0, 2.0, 3.0))


def test_aim_step_emits_cue_and_command_with_capture_time() -> None:
    state, out = aim_step(AimState(), scans(ray(0.0, 0.030, 0.045)), T0 + 5_000_000)
    cue, command = out
    assert cue.state == "guiding" and cue.frame_seq == 1
    assert cue.t_ns == command.t_ns == T0
    assert cue.theta_deg == pytest.approx(0.0, abs=1e-4)
    assert command.amplitudes == pytest.approx([0.7, 0, 0, 0], abs=1e-6)
    assert not command.pulse
    assert state.seq == 1


@pytest.mark.parametrize(
    ("follow", "wrist_deg", "expected"),
    [
        (True, 90.0, [0, 0.7, 0, 0]),  # the wrist (and camera) turned a quarter: tactor 1
        (True, -45.0, [0.35, 0, 0, 0.35]),  # halfway between tactors 3 and 0
        (False, 90.0, [0.7, 0, 0, 0]),  # camera fixed: the wrist does not matter
    ],
)
def test_aim_step_tactor_directions_turn_with_the_wrist(
    follow: bool, wrist_deg: float, expected: list[float]
) -> None:
    """An object seen to the right (image angle 0) lies at forearm direction wrist + 0, so
    with the camera on the hand the tactor at that forearm direction vibrates."""
    state = AimState(params=AimParams(follow_wrist=follow))
    hand = ProsthesisState(seq=1, t_ns=T0, wrist_angle_deg=wrist_deg, aperture_mm=80.0)
    state, out = aim_step(state, hand, T0)
    assert out == []
    _, (cue, command) = aim_step(state, scans(ray(0.0, 0.030, 0.045)), T0)
    assert cue.theta_deg == pytest.approx(0.0, abs=1e-4)  # the cue's image direction is kept
    assert command.amplitudes == pytest.approx(expected, abs=1e-6)


def test_aim_step_ready_pulses_only_with_a_fresh_reconstruction() -> None:
    on = scans(patch(-0.01, 0.01, -0.01, 0.01))
    state, out = aim_step(AimState(), on, T0)
    assert out[0].state == "on_target" and not out[1].pulse
    state, out = aim_step(state, target(reconstructed=False), T0)
    assert out == []
    state, out = aim_step(state, on, T0)
    assert out[0].state == "on_target"
    state, _ = aim_step(state, target(reconstructed=True), T0)
    state, out = aim_step(state, on, T0)
    assert out[0].state == "ready" and out[1].pulse
    assert out[1].amplitudes == [1.0] * 4
    late = scans(patch(-0.01, 0.01, -0.01, 0.01), t_ns=T0 + 2_000_000_000)
    _, out = aim_step(state, late, T0)
    assert out[0].state == "on_target"  # the reconstruction is 2 s old: not ready


def test_aim_step_nothing_in_view_commands_all_off() -> None:
    _, (cue, command) = aim_step(AimState(), scans(np.empty((0, 3))), T0)
    assert cue.state == "nothing" and cue.objects == 0
    assert command.amplitudes == [0.0] * 4


def controller(state: str, seq: int = 1) -> ControllerState:
    return ControllerState(seq=seq, t_ns=T0, state=state)  # type: ignore[arg-type]


def test_aim_step_cues_off_while_the_controller_has_stopped_the_hand() -> None:
    right = ray(0.0, 0.030, 0.045)
    on = patch(-0.01, 0.01, -0.01, 0.01)
    state, _ = aim_step(AimState(), target(reconstructed=True), T0)
    state, out = aim_step(state, controller("stopped"), T0)
    assert out == [] and state.controller == "stopped"
    for i, points in enumerate((right, on, np.empty((0, 3)))):
        state, (cue, command) = aim_step(state, scans(points, seq=2 + i), T0)
        # A cue and a command every frame, so the bridge keeps sending all-off.
        assert cue.state == "nothing" and cue.frame_seq == 2 + i
        assert cue.amplitudes == command.amplitudes == [0.0] * 4
        assert not command.pulse
    assert state.seq == 3
    # Leaving "stopped" (the controller recovered to idle): the cues are back at once.
    state, _ = aim_step(state, controller("idle"), T0)
    state, (cue, command) = aim_step(state, scans(right, seq=5), T0)
    assert cue.state == "guiding" and command.amplitudes == pytest.approx([0.7, 0, 0, 0], abs=1e-6)
    state, _ = aim_step(state, controller("ready"), T0)
    _, (cue, command) = aim_step(state, scans(on, seq=6), T0)
    assert cue.state == "ready" and command.pulse and command.amplitudes == [1.0] * 4


def test_aim_step_stopped_keeps_tracking_the_chosen_object() -> None:
    # Two objects at equal distance: the one chosen before the stop is still chosen after it.
    left = patch(-0.040, -0.015, -0.005, 0.005)
    right = patch(0.015, 0.040, -0.005, 0.005)
    state, (cue, _) = aim_step(AimState(), scans(left), T0)
    chosen = state.chosen_xy
    assert chosen is not None and chosen[0] < 0
    state, _ = aim_step(state, controller("stopped"), T0)
    state, (cue, _) = aim_step(state, scans(np.concatenate([right, left])), T0)
    assert cue.state == "nothing" and cue.objects == 2
    assert state.chosen_xy == pytest.approx(chosen, abs=1e-9)
    state, _ = aim_step(state, controller("aiming"), T0)
    _, (cue, command) = aim_step(state, scans(np.concatenate([right, left])), T0)
    assert cue.theta_deg % 360.0 == pytest.approx(180.0, abs=1e-6)  # still the left one
    assert command.amplitudes == pytest.approx([0, 0, 0.85, 0], abs=1e-6)


def test_aim_step_bad_points_shape_raises_value_error() -> None:
    bad = ScanLines(
        seq=1,
        t_ns=T0,
        frame_seq=1,
        lines=[ScanLine(angle_deg=0.0, points=to_wire(np.zeros((4, 2), np.float32)))],
    )
    with pytest.raises(ValueError, match="scan line 0"):
        aim_step(AimState(), bad, T0)


def test_aim_step_non_finite_point_raises_value_error() -> None:
    line = ray(0.0, 0.030, 0.045).astype(np.float32)
    line[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN or inf"):
        aim_step(AimState(), scans(ray(90.0, 0.010, 0.020), line), T0)


def test_aim_step_same_cue_from_float32_and_float64_lines() -> None:
    # The scans service sends float32 (N, 3) lines, which the step reads as one array; any
    # other dtype goes line by line, and must point the same way.
    lines = [ray(0.0, 0.030, 0.045), ray(45.0, 0.030, 0.040), patch(0.02, 0.03, 0.02, 0.03)]
    narrow = scans(*lines)
    wide = ScanLines(
        seq=1,
        t_ns=T0,
        frame_seq=1,
        lines=[
            ScanLine(angle_deg=line.angle_deg, points=to_wire(from_wire(line.points).astype(float)))
            for line in narrow.lines
        ],
    )
    _, (cue32, command32) = aim_step(AimState(), narrow, T0)
    _, (cue64, command64) = aim_step(AimState(), wide, T0)
    assert cue32.state == "guiding" and cue32.objects == 2
    assert cue64 == cue32 and command64 == command32


def test_aim_service_publishes_command_and_cue_per_frame(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    got: dict[str, list] = {"lpc/tactors/command": [], "lpc/aim/cue": []}
    lock = threading.Lock()

    def on_sample(sample) -> None:
        key = str(sample.key_expr)
        with lock:
            got[key].append(decode(key, sample.payload.to_bytes()))

    subs = [rendezvous.declare_subscriber(k, on_sample) for k in got]
    proc = spawn_service("services.aim", endpoint)
    try:
        right = scans(ray(0.0, 0.030, 0.045), t_ns=T0)

        def guided() -> bool:
            rendezvous.put("lpc/scans", encode(right))
            with lock:
                return any(c.t_ns == T0 for c in got["lpc/tactors/command"])

        wait_for(guided, 30.0, "a tactor command for the frame")
        on = scans(patch(-0.01, 0.01, -0.01, 0.01), t_ns=T0 + 1)
        rendezvous.put("lpc/grasp/target", encode(target(reconstructed=True, t_ns=T0)))

        def ready() -> bool:
            rendezvous.put("lpc/scans", encode(on))
            with lock:
                return any(c.pulse for c in got["lpc/tactors/command"])

        wait_for(ready, 10.0, "a pulsing command once reconstructed")
        with lock:
            first = next(c for c in got["lpc/tactors/command"] if c.t_ns == T0)
            cues = list(got["lpc/aim/cue"])
        assert first.amplitudes == pytest.approx([0.7, 0, 0, 0], abs=1e-6)
        assert any(c.state == "guiding" and c.t_ns == T0 for c in cues)

        # The controller stops the hand: the same view gives all-off, frame after frame. An
        # all-off command acknowledges that the service has taken "stopped" in.
        def commands(t_ns: int) -> list[TactorCommand]:
            with lock:
                return [c for c in got["lpc/tactors/command"] if c.t_ns == t_ns]

        def put_until(t_ns: int, state: str, amplitudes: list[float]) -> Callable[[], bool]:
            def seen() -> bool:
                rendezvous.put("lpc/controller/state", encode(controller(state)))
                rendezvous.put("lpc/scans", encode(scans(ray(0.0, 0.030, 0.045), t_ns=t_ns)))
                return any(c.amplitudes == pytest.approx(amplitudes) for c in commands(t_ns))

            return seen

        wait_for(put_until(T0 + 2, "stopped", [0.0] * 4), 10.0, "an all-off command")
        wait_for(put_until(T0 + 3, "stopped", [0.0] * 4), 10.0, "a second all-off command")
        assert all(c.amplitudes == [0.0] * 4 for c in commands(T0 + 3))
        with lock:
            assert all(c.state == "nothing" for c in got["lpc/aim/cue"] if c.t_ns == T0 + 3)
        wait_for(put_until(T0 + 4, "idle", [0.7, 0, 0, 0]), 10.0, "the cue back once recovered")
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        for sub in subs:
            sub.undeclare()


def _cube_linkage(points: np.ndarray, gap_m: float) -> np.ndarray:
    """cluster_points' definition, written plainly: the first point of each cube of side
    gap / 4 (cubes in (x, y, z) cell order) stands for its cube, two of them closer than the
    gap are linked, and each point takes its cube's component, labelled by its first cube."""
    cells = [tuple(c) for c in np.floor(points / (gap_m / 4.0)).astype(np.int64).tolist()]
    cubes = sorted(set(cells))
    index = {c: k for k, c in enumerate(cubes)}
    first = {}
    for i, c in enumerate(cells):
        first.setdefault(index[c], i)
    reps = points[[first[k] for k in range(len(cubes))]]
    label = list(range(len(cubes)))

    def root(k: int) -> int:
        while label[k] != k:
            k = label[k]
        return k

    for a in range(len(cubes)):
        for b in range(a + 1, len(cubes)):
            if float(np.sum((reps[a] - reps[b]) ** 2)) <= gap_m * gap_m:
                ra, rb = root(a), root(b)
                label[max(ra, rb)] = min(ra, rb)
    return np.array([root(index[c]) for c in cells])


@pytest.mark.parametrize("seed", range(6))
def test_cluster_points_is_single_linkage_of_the_cubes_first_points(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # Two to four blobs of scattered points in the capture volume, some closer than the gap.
    centres = rng.uniform([-0.04, -0.04, 0.16], [0.04, 0.04, 0.24], (int(rng.integers(2, 5)), 3))
    points = np.concatenate([c + rng.normal(0.0, 0.006, (60, 3)) for c in centres])
    points = points[rng.permutation(len(points))]
    labels = cluster_points(points, 0.010)
    assert labels.tolist() == _cube_linkage(points, 0.010).tolist()


def test_cluster_points_links_a_cloud_of_more_cubes_than_one_leaf_as_defined() -> None:
    # A frame's cubes fit in the k-d tree's one leaf; a larger cloud's tree splits.
    rng = np.random.default_rng(11)
    centres = rng.uniform([-0.04, -0.04, 0.16], [0.04, 0.04, 0.24], (6, 3))
    points = np.concatenate([c + rng.normal(0.0, 0.006, (60, 3)) for c in centres])
    cubes = len(np.unique(np.floor(points / 0.0025), axis=0))
    assert cubes > aim._LEAF_CUBES
    labels = cluster_points(points, 0.010)
    assert labels.tolist() == _cube_linkage(points, 0.010).tolist()


def test_cluster_points_keeps_far_points_in_order_and_refuses_beyond_its_cells() -> None:
    # The cube keys' fixed radix holds cells within +-2**16 of the camera: 163 m at this gap.
    rng = np.random.default_rng(7)
    blobs = np.concatenate([c + rng.normal(0.0, 0.006, (60, 3)) for c in ([0, 0, 0], [0.02] * 3)])
    far = blobs + np.array([-160.0, 150.0, 160.0])
    assert cluster_points(far, 0.010).tolist() == _cube_linkage(far, 0.010).tolist()
    with pytest.raises(ValueError, match=r"163\.84 m"):
        cluster_points(blobs + np.array([0.0, 0.0, 164.0]), 0.010)
