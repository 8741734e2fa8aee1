"""Tests for lpc_core.sim.scene: analytic primitives, the renderer's geometry, its noise."""

from __future__ import annotations

import numpy as np
import pytest

from lpc_core.perception.intrinsics import D435_424X240, Intrinsics
from lpc_core.sim.scene import (
    BumpyEllipsoid,
    Cone,
    ConvexPolyhedron,
    Cuboid,
    Cylinder,
    Ellipsoid,
    NoiseModel,
    Plane,
    Rays,
    Scene,
    Sphere,
    Superellipsoid,
    aim_pose,
    apply_noise,
    exact_depth,
    functional_objects,
    irregular_objects,
    look_at,
    make_pose,
    render_depth,
    rotation_about,
    sphere_object,
)

INTR = D435_424X240
IDENTITY = np.eye(4)  # world = camera frame: x right, y down, z forward
MM = 1e-3


def _rays_grid(intr: Intrinsics) -> np.ndarray:
    xs, ys = intr.pixel_rays()
    return np.stack([xs, ys, np.ones_like(xs)], axis=-1)  # (H, W, 3), z = 1


def _wall(z: float) -> Plane:
    return Plane(np.array([0.0, 0.0, z]), np.array([0.0, 0.0, -1.0]))


# ----------------------------------------------------------------- independent inside tests


def _sdf_box(p: np.ndarray, center, rotation, size) -> np.ndarray:
    q = np.abs((p - center) @ rotation) - 0.5 * np.asarray(size)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    return outside + np.minimum(q.max(axis=-1), 0.0)


def _sdf_cylinder(p: np.ndarray, center, axis, radius, length) -> np.ndarray:
    w = p - center
    h = w @ axis
    radial = np.linalg.norm(w - h[..., None] * axis, axis=-1)
    d = np.stack([radial - radius, np.abs(h) - 0.5 * length], axis=-1)
    return np.minimum(d.max(axis=-1), 0.0) + np.linalg.norm(np.maximum(d, 0.0), axis=-1)


def _hex_vertices(across: float, length: float) -> np.ndarray:
    r = across / np.sqrt(3.0)
    ang = np.radians(np.arange(6) * 60.0)
    ring = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    return np.vstack([np.column_stack([ring, np.full(6, s * length / 2)]) for s in (-1, 1)])


_TILT = rotation_about((1.0, 0.3, 0.2), 0.7)
_C = np.array([0.01, -0.008, 0.22])

# (primitive, inside(points) -> bool) pairs; the inside tests are written independently.
_CASES = {
    "sphere": (
        Sphere(_C, 0.03),
        lambda p: np.linalg.norm(p - _C, axis=-1) <= 0.03,
    ),
    "cylinder": (
        Cylinder(_C, _TILT[:, 2], 0.025, 0.09),
        lambda p: _sdf_cylinder(p, _C, _TILT[:, 2], 0.025, 0.09) <= 0.0,
    ),
    "cylinder_along_view": (
        Cylinder(np.array([0.0, 0.0, 0.22]), np.array([0.0, 0.0, 1.0]), 0.045, 0.05),
        lambda p: (
            _sdf_cylinder(p, np.array([0, 0, 0.22]), np.array([0, 0, 1.0]), 0.045, 0.05) <= 0.0
        ),
    ),
    "cone": (
        Cone(_C, _TILT[:, 1], 0.035, 0.02, 0.08),
        lambda p: (
            (np.abs((p - _C) @ _TILT[:, 1]) <= 0.04)
            & (
                np.linalg.norm(
                    (p - _C) - ((p - _C) @ _TILT[:, 1])[..., None] * _TILT[:, 1], axis=-1
                )
                <= 0.035 + (0.02 - 0.035) * (((p - _C) @ _TILT[:, 1]) + 0.04) / 0.08
            )
        ),
    ),
    "cuboid": (
        Cuboid(_C, _TILT, np.array([0.06, 0.03, 0.045])),
        lambda p: _sdf_box(p, _C, _TILT, (0.06, 0.03, 0.045)) <= 0.0,
    ),
    "ellipsoid": (
        Ellipsoid(_C, _TILT, np.array([0.04, 0.02, 0.03])),
        lambda p: np.sum((((p - _C) @ _TILT) / (0.04, 0.02, 0.03)) ** 2, axis=-1) <= 1.0,
    ),
    "hex_prism": (
        ConvexPolyhedron(_C, _TILT, _hex_vertices(0.04, 0.08)),
        lambda p: (
            (np.abs(((p - _C) @ _TILT)[..., 2]) <= 0.04)
            & np.all(
                np.stack(
                    [
                        ((p - _C) @ _TILT)[..., :2] @ np.array([np.cos(a), np.sin(a)])
                        for a in np.radians(np.arange(6) * 60.0 + 30.0)
                    ],
                    axis=-1,
                )
                <= 0.02 + 1e-12,
                axis=-1,
            )
        ),
    ),
    "superellipsoid": (
        Superellipsoid(_C, _TILT, np.array([0.045, 0.03, 0.015]), exponent=4.0),
        lambda p: np.sum(np.abs(((p - _C) @ _TILT) / (0.045, 0.03, 0.015)) ** 4, axis=-1) <= 1.0,
    ),
    "bumpy_ellipsoid": (
        BumpyEllipsoid(_C, _TILT, np.array([0.05, 0.03, 0.025]), amplitude=0.06),
        None,  # checked against its own implicit function below
    ),
}


@pytest.mark.parametrize("name", sorted(_CASES))
def test_primitive_intersect_matches_brute_force(name: str) -> None:
    prim, inside = _CASES[name]
    if inside is None:
        inside = lambda p: prim._f((p - prim.center) @ prim.rotation) <= 0.0  # noqa: E731
    rng = np.random.default_rng(7)
    d = np.column_stack([rng.uniform(-0.3, 0.3, 300), rng.uniform(-0.3, 0.3, 300), np.ones(300)])
    d[0] = (0.0, 0.0, 1.0)  # the optical axis, parallel to some axes
    t = prim.intersect(Rays(d[:, 0], d[:, 1], d[:, 2]))
    step = 1e-4
    ts = np.arange(0.10, 0.34, step)
    hit = inside(ts[None, :, None] * d[:, None, :])
    brute = np.where(hit.any(axis=1), ts[np.argmax(hit, axis=1)], np.inf)
    both = np.isfinite(brute) & np.isfinite(t)
    assert both.sum() > 40, "the cases must hit the solid with a good share of rays"
    # The analytic hit lies within one sampling step before the first inside sample.
    assert np.all(t[both] <= brute[both] + 1e-9)
    assert np.all(t[both] >= brute[both] - step - 2e-6)
    # Disagreement on hit/miss only for grazing rays, whose chord is below the sampling step.
    assert np.count_nonzero(np.isfinite(brute) != np.isfinite(t)) <= 3


# ----------------------------------------------------------------- rendering geometry


def test_render_sphere_depth_within_quantisation() -> None:
    c, r = np.array([0.012, -0.006, 0.2]), 0.03
    depth = render_depth(
        Scene((), None), INTR, IDENTITY, np.random.default_rng(0), NoiseModel.exact()
    )
    assert not depth.any()  # empty scene: no returns
    scene = Scene((sphere_object("ball", c, r),), None)
    depth = render_depth(scene, INTR, IDENTITY, np.random.default_rng(0), NoiseModel.exact())
    d = _rays_grid(INTR)
    dd = np.sum(d * d, axis=-1)
    b = d @ c
    disc = b * b - dd * (c @ c - r * r)
    z_true = np.where(disc >= 0, (b - np.sqrt(np.maximum(disc, 0))) / dd, np.inf)
    clear = np.abs(disc) > 1e-6 * dd  # away from the exact silhouette
    assert np.array_equal((depth > 0)[clear], np.isfinite(z_true)[clear])
    on = (depth > 0) & np.isfinite(z_true)
    assert on.sum() > 3000
    assert np.max(np.abs(depth[on] * 1e-3 - z_true[on])) <= 0.5e-3 + 1e-6


@pytest.mark.parametrize("kind", ["cylinder", "cuboid"])
def test_render_cylinder_cuboid_points_on_surface(kind: str) -> None:
    objs = functional_objects()
    obj = objs["cylinder_tilt_left"] if kind == "cylinder" else objs["cuboid_tilt_right"]
    pose = aim_pose(obj, 0.19, elevation_rad=np.radians(25.0), azimuth_rad=0.3)
    depth = render_depth(
        Scene((obj,), None), INTR, pose, np.random.default_rng(0), NoiseModel.exact()
    )
    part = obj.parts[0]
    # Deprojected points, back to the world frame.
    d = _rays_grid(INTR)
    valid = depth > 0
    assert valid.sum() > 2000
    p_cam = depth[valid][:, None] * 1e-3 * d[valid]
    dirs = d[valid] / np.linalg.norm(d[valid], axis=1, keepdims=True)
    to_world = lambda p: p @ pose[:3, :3].T + pose[:3, 3]  # noqa: E731
    if kind == "cylinder":
        sdf = lambda p: _sdf_cylinder(p, part.center, part.axis, part.radius, part.length)  # noqa: E731
    else:
        sdf = lambda p: _sdf_box(p, part.center, part.rotation, part.size)  # noqa: E731
    norm_d = np.linalg.norm(d[valid], axis=1)
    # sdf is 1-Lipschitz: a point within 0.5 mm of depth of the surface is within
    # 0.5 mm * |d| of it in space.
    assert np.all(np.abs(sdf(to_world(p_cam))) <= 0.5e-3 * norm_d + 1e-6)
    # Front faces only: 1 mm nearer along the ray is outside the (convex) solid.
    assert np.all(sdf(to_world(p_cam - 1e-3 * dirs)) > 0)
    # Rays with no depth around the silhouette miss the solid: sample them along the ray.
    rows, cols = np.nonzero(valid)
    near = np.zeros_like(valid)
    near[max(rows.min() - 5, 0) : rows.max() + 6, max(cols.min() - 5, 0) : cols.max() + 6] = True
    dm = d[near & ~valid][::3]
    ts = np.arange(0.12, 0.40, 1e-3)
    pts = to_world(ts[None, :, None] * dm[:, None, :])
    assert np.all(sdf(pts.reshape(-1, 3)) > -1e-4)


def test_render_with_table_occludes_behind() -> None:
    obj = functional_objects()["sphere_large"]
    pose = aim_pose(obj, 0.19)
    with_table = exact_depth(Scene((obj,), Plane(np.zeros(3), np.array([0, 0, 1.0]))), INTR, pose)
    alone = exact_depth(Scene((obj,), None), INTR, pose)
    on_obj = np.isfinite(alone)
    assert np.allclose(with_table[on_obj], alone[on_obj])  # the table is behind the ball
    assert np.isfinite(with_table[~on_obj]).mean() > 0.5


# ----------------------------------------------------------------- noise model


def test_noise_range_rms_matches_formula_figures() -> None:
    noise = NoiseModel()
    assert noise.range_rms_m(0.150, 213.0) == pytest.approx(0.17e-3, rel=0.03)
    assert noise.range_rms_m(0.250, 213.0) == pytest.approx(0.47e-3, rel=0.03)


@pytest.mark.parametrize("z0", [0.150, 0.250])
def test_noise_range_rms_matches_model(z0: float) -> None:
    fine = Intrinsics(depth_scale=1e-5)  # 10 µm unit: quantisation well below the noise
    noise = NoiseModel(flying_probability=0.0, hole_fraction=0.0, shadow=False)
    depth = render_depth(Scene((), _wall(z0)), fine, IDENTITY, np.random.default_rng(1), noise)
    err = depth.astype(np.float64) * 1e-5 - z0
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms == pytest.approx(noise.range_rms_m(z0, fine.fx), rel=0.2)
    assert abs(float(np.mean(err))) < 0.1 * rms  # unbiased


def test_noise_holes_fraction() -> None:
    noise = NoiseModel.exact(hole_fraction=0.02)
    depth = render_depth(Scene((), _wall(0.2)), INTR, IDENTITY, np.random.default_rng(2), noise)
    frac = float(np.mean(depth == 0))
    # Binomial: sd = sqrt(p (1 - p) / N) ~ 0.00044 for N = 101760.
    assert frac == pytest.approx(0.02, abs=0.002)
    assert np.all(depth[depth > 0] == 200)


def _ball_before_wall() -> tuple[Scene, np.ndarray]:
    c = np.array([0.0, 0.0, 0.2])
    return Scene((sphere_object("ball", c, 0.03),), _wall(0.4)), c


def test_noise_flying_pixels_only_at_edges() -> None:
    scene, _ = _ball_before_wall()
    z = exact_depth(scene, INTR, IDENTITY)
    noise = NoiseModel.exact(flying_probability=1.0)
    clean = render_depth(scene, INTR, IDENTITY, np.random.default_rng(3), NoiseModel.exact())
    flying = render_depth(scene, INTR, IDENTITY, np.random.default_rng(3), noise)
    changed = flying.astype(int) != clean.astype(int)
    # Edge pixels: some 4-neighbour's disparity (fx B / z) differs by more than the jump.
    disp = INTR.fx * noise.baseline_m / z
    pad_d = np.pad(disp, 1, constant_values=0.0)
    pad = np.pad(z, 1, constant_values=np.nan)
    edge = np.zeros_like(changed)
    lo_nb = np.full(z.shape, np.inf)
    hi_nb = np.full(z.shape, -np.inf)
    for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        rows = slice(1 + dv, 1 + dv + z.shape[0])
        cols = slice(1 + du, 1 + du + z.shape[1])
        edge |= (pad_d[rows, cols] > 0) & (np.abs(pad_d[rows, cols] - disp) > noise.flying_jump_px)
        lo_nb = np.fmin(lo_nb, pad[rows, cols])
        hi_nb = np.fmax(hi_nb, pad[rows, cols])
    assert changed.sum() > 100
    assert np.all(edge[changed])
    # A flying pixel's depth lies between its own and its neighbours' (1 mm rounding slack).
    mm = flying[changed] * 1e-3
    assert np.all(mm >= np.fmin(z, lo_nb)[changed] - 1e-3)
    assert np.all(mm <= np.fmax(z, hi_nb)[changed] + 1e-3)


def test_noise_shadow_on_the_left_of_near_object() -> None:
    scene, c = _ball_before_wall()
    r, z_wall, baseline = 0.03, 0.4, 0.05
    noise = NoiseModel.exact(shadow=True, baseline_m=baseline)
    depth = render_depth(scene, INTR, IDENTITY, np.random.default_rng(4), noise)
    ball = (depth > 0) & (depth < 300)
    holes = depth == 0
    assert holes.sum() > 200
    rows = np.flatnonzero(holes.any(axis=1))
    for row in rows:
        ball_cols = np.flatnonzero(ball[row])
        assert ball_cols.size > 0, "shadow only on rows the ball covers"
        assert np.flatnonzero(holes[row]).max() < ball_cols.min()  # strictly left of the ball

    # Centre row: the wall between the two left tangents (from the camera and from the second
    # imager at +B) is hidden: width fx (x1 - x2) / z_wall.
    def left_tangent_at_wall(ox: float) -> float:
        vx, vz = c[0] - ox, c[2]
        dist = np.hypot(vx, vz)
        ang = np.arctan2(vx, vz) - np.arcsin(r / dist)
        return ox + z_wall * np.tan(ang)

    width_px = INTR.fx * (left_tangent_at_wall(0.0) - left_tangent_at_wall(baseline)) / z_wall
    centre_row = int(INTR.ppy)
    measured = np.count_nonzero(holes[centre_row])
    assert measured == pytest.approx(width_px, abs=1.5)


def test_noise_range_limits_give_zero() -> None:
    rng = np.random.default_rng(5)
    too_near = render_depth(Scene((), _wall(0.08)), INTR, IDENTITY, rng, NoiseModel.exact())
    too_far = render_depth(Scene((), _wall(5.0)), INTR, IDENTITY, rng, NoiseModel.exact())
    assert not too_near.any() and not too_far.any()


def test_render_deterministic_per_seed() -> None:
    obj = functional_objects()["cylinder_upright"]
    scene = Scene((obj,), Plane(np.zeros(3), np.array([0, 0, 1.0])))
    pose = aim_pose(obj, 0.2)
    a = render_depth(scene, INTR, pose, np.random.default_rng(11))
    b = render_depth(scene, INTR, pose, np.random.default_rng(11))
    c = render_depth(scene, INTR, pose, np.random.default_rng(12))
    assert a.dtype == np.uint16 and a.shape == (240, 424)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


# ----------------------------------------------------------------- ground truth


def _front(obj, elevation_deg: float = 0.0) -> np.ndarray:
    return aim_pose(obj, 0.19, azimuth_rad=0.0, elevation_rad=np.radians(elevation_deg))


@pytest.mark.parametrize(
    ("name", "width_mm", "angle_deg"),
    [
        ("cylinder_tilt_left", 75.0, 60.0),
        ("cylinder_tilt_right", 50.0, -60.0),
        ("cylinder_lying", 40.0, 0.0),
        ("cuboid_tilt_left", 45.0, 60.0),
        ("cuboid_tilt_right", 85.0, -60.0),
        ("cuboid_upright", 35.0, -90.0),
    ],
)
def test_truth_tilted_objects_wrist_angle(name: str, width_mm: float, angle_deg: float) -> None:
    # Seen from the front at the object's height, a 30-degree tilt from vertical is a line at
    # 60 degrees from the image x axis: tilted left (top toward -x) runs down-right, +60.
    obj = functional_objects()[name]
    truth = obj.truth(_front(obj))
    assert truth.pierced
    assert truth.grasp_width_mm == pytest.approx(width_mm, abs=1e-6)
    assert truth.wrist_angle_deg == pytest.approx(angle_deg, abs=1e-6)
    assert -90.0 <= truth.wrist_angle_deg < 90.0


def test_truth_cuboid_pierced_face_changes_with_view() -> None:
    box = functional_objects()["cuboid_lying"]  # 150 x 70 x 40, long side along world x
    front = box.truth(_front(box))
    above = box.truth(_front(box, elevation_deg=90.0))
    assert front.grasp_width_mm == pytest.approx(40.0)
    assert above.grasp_width_mm == pytest.approx(70.0)
    assert front.wrist_angle_deg == pytest.approx(0.0, abs=1e-6)
    assert above.wrist_angle_deg == pytest.approx(0.0, abs=1e-6)


def test_truth_camera_roll_turns_the_wrist_angle() -> None:
    obj = functional_objects()["cylinder_lying"]
    rolled = aim_pose(obj, 0.19, elevation_rad=0.0, roll_rad=np.radians(20.0))
    # Rolling the camera by +20 degrees about its z axis turns the image by -20 degrees.
    assert obj.truth(rolled).wrist_angle_deg == pytest.approx(-20.0, abs=1e-6)


def test_truth_sphere_and_axis_along_view_have_no_angle() -> None:
    ball = functional_objects()["sphere_small"]
    assert ball.truth(_front(ball)).wrist_angle_rad is None
    cap = irregular_objects()["jar_cap"]
    from_above = cap.truth(_front(cap, elevation_deg=90.0))
    assert from_above.pierced and from_above.wrist_angle_rad is None
    assert from_above.grasp_width_mm == pytest.approx(60.0)


def test_truth_misses_when_axis_off_object() -> None:
    obj = functional_objects()["sphere_small"]
    off = _front(obj) @ make_pose(None, (0.05, 0.0, 0.0))
    truth = obj.truth(off)
    assert not truth.pierced and truth.pierce_depth_m is None
    assert truth.center[0] == pytest.approx(-0.05, abs=1e-9)


def test_functional_objects_match_paper_set() -> None:
    objs = functional_objects()
    shapes = [o.shape for o in objs.values()]
    assert len(objs) == 10
    assert (shapes.count("sphere"), shapes.count("cylinder"), shapes.count("cuboid")) == (2, 4, 4)
    for obj in objs.values():
        assert obj.lowest_z() == pytest.approx(0.0, abs=1e-9)  # resting on the table
        assert 35.0 <= obj.truth(_front(obj, 20.0)).grasp_width_mm <= 85.0


@pytest.mark.parametrize("name", sorted(irregular_objects()))
def test_aim_pose_pierces_every_object_at_distance(name: str) -> None:
    obj = irregular_objects()[name]
    pose = aim_pose(obj, 0.19, elevation_rad=np.radians(30.0))
    truth = obj.truth(pose)
    assert truth.pierced
    assert truth.pierce_depth_m == pytest.approx(0.19, abs=1e-6)
    z = exact_depth(Scene((obj,), None), INTR, pose)
    centre = z[int(INTR.ppy), int(INTR.ppx)]
    assert centre == pytest.approx(0.19, abs=2e-3)  # pixel centre vs the exact axis
    assert np.isfinite(z).sum() > 500


def test_look_at_axes() -> None:
    pose = look_at((0.1, -0.3, 0.2), (0.0, 0.0, 0.05))
    rot = pose[:3, :3]
    assert np.allclose(rot.T @ rot, np.eye(3)) and np.linalg.det(rot) == pytest.approx(1.0)
    forward = np.array([-0.1, 0.3, -0.15]) / np.linalg.norm([-0.1, 0.3, -0.15])
    assert np.allclose(rot[:, 2], forward)
    assert rot[:, 1] @ np.array([0, 0, 1.0]) < 0  # image down points down in the world
    assert rot[:, 0] @ np.array([0, 0, 1.0]) == pytest.approx(0.0, abs=1e-12)


def test_invalid_inputs_raise_value_error_naming_parameter() -> None:
    with pytest.raises(ValueError, match="radius"):
        Sphere(np.zeros(3), -1.0)
    with pytest.raises(ValueError, match="camera_pose"):
        render_depth(Scene(), INTR, np.eye(3), np.random.default_rng(0))
    with pytest.raises(ValueError, match="depth_m"):
        apply_noise(np.zeros((10, 10)), INTR, np.random.default_rng(0))
    with pytest.raises(ValueError, match="hole_fraction"):
        NoiseModel(hole_fraction=2.0)
    with pytest.raises(ValueError, match="rotation"):
        Cuboid(np.zeros(3), np.diag([1.0, 1.0, -1.0]), np.ones(3))


def test_noise_no_flying_pixels_on_a_plane_at_grazing_view() -> None:
    # A table seen nearly edge-on: depth grows fast between rows, but its disparity step per
    # row stays far below the jump, so nothing flies.
    table_only = Scene((), Plane(np.zeros(3), np.array([0.0, 0.0, 1.0])))
    pose = look_at((0.0, -0.3, 0.05), (0.0, 0.5, 0.0))
    noise = NoiseModel.exact(flying_probability=1.0)
    clean = render_depth(table_only, INTR, pose, np.random.default_rng(0), NoiseModel.exact())
    flying = render_depth(table_only, INTR, pose, np.random.default_rng(0), noise)
    assert (clean > 0).sum() > 20000
    assert np.array_equal(clean, flying)
