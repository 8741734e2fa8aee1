"""A simulated active stereo camera (D435-like): two IR images of the scene lit by a dot
projector, matched by a real stereo matcher (OpenCV's StereoSGBM or StereoBM) into depth.

Unlike ``scene.NoiseModel``, which perturbs an exact depth image pixel by pixel, the errors
here come from matching, as on the device: edge fattening next to occluding edges (the
matching window straddles the edge and the textured foreground wins), holes where matching
fails (occlusion, the projector's shadow, grazing or dim surfaces), the sub-pixel staircase
of a 1/16 px disparity and errors correlated over the matching window.

Geometry (camera frame as RealSense: x right, y down, z forward, metres):

- the left imager is the depth frame's origin, as on a D435; the right imager sits
  ``baseline_m`` along +x; both share the depth stream's intrinsics and are rectified, so a
  point at depth z appears in the right image ``fx * baseline_m / z`` px to the left;
- the projector sits between them at ``projector_x_m``; its dot pattern is fixed in the
  projector's angular coordinates (a property of the device, seeded by ``pattern_seed``);
- a surface point's irradiance is the pattern times ``cos / r²`` from the projector (zero
  where the projector cannot see it: the ray toward it meets the scene first), plus a dim
  ambient term; surfaces are Lambertian, so each imager sees the same radiance;
- the images get an optics blur, shot and read noise, and 8-bit quantisation.

A frame is a pure function of its arguments: the pattern from ``pattern_seed``, the sensor
noise from the ``rng`` passed in (seed it from the frame's ``seq``).

Both images are rendered ``num_disparities`` columns wider on the left, so that OpenCV's
matchers (which give no output for the first ``num_disparities`` columns) cover the whole
depth image; the device's own invalid band (left pixels whose match would fall outside the
right imager) is then restored by ``StereoRig.left_band``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.sim.scene import Rays, Scene, check_pose, exact_depth, invert_pose, make_pose
from lpc_core.sim.stereo_settings import Matcher, StereoRig, import_cv2

_SHADOW_TOL_M = 1e-4
"""A ray from the projector that meets the scene this much before the point is shadowed."""

_REFERENCE_RANGE_M = 0.2
"""Irradiance is normalised to a dot's peak on a fronto-parallel surface at this range."""


@dataclass(frozen=True, eq=False)
class IrPair:
    """Left and right 8-bit IR images, ``pad`` columns wider on the left than the depth image."""

    left: np.ndarray
    right: np.ndarray
    pad: int


# --------------------------------------------------------------------------- the dot pattern

_PATTERN_OVERSAMPLE = 2
_PATTERN_HALF_FIELD = (1.6, 0.9)
"""The projector's field: x/z and y/z up to these (wider than the imagers' with any pad)."""


@lru_cache(maxsize=8)
def _dot_pattern(
    fx: float, fy: float, density: float, sigma_px: float, brightness: tuple, seed: int
) -> np.ndarray:
    """The projector's pattern on its angular grid (``fx * _PATTERN_OVERSAMPLE`` px per unit
    of x/z), centred on its axis: Gaussian dots of random brightness, a lone dot peaking at its
    brightness. Fixed for a device: it depends on the focal length, not on the image size."""
    cv2 = import_cv2()
    s = _PATTERN_OVERSAMPLE
    w = int(np.ceil(2 * _PATTERN_HALF_FIELD[0] * fx * s))
    h = int(np.ceil(2 * _PATTERN_HALF_FIELD[1] * fy * s))
    rng = np.random.default_rng([seed, 0x5D07])
    n = rng.poisson(density * w * h / (s * s))
    xs = rng.uniform(0, w - 1, n)
    ys = rng.uniform(0, h - 1, n)
    level = rng.uniform(brightness[0], brightness[1], n)
    impulses = np.zeros((h, w), dtype=np.float32)
    # Bilinear splat, so a dot's centre is not snapped to the pattern's grid.
    x0, y0 = np.floor(xs).astype(np.int64), np.floor(ys).astype(np.int64)
    ax, ay = xs - x0, ys - y0
    for dx, dy, wgt in (
        (0, 0, (1 - ax) * (1 - ay)),
        (1, 0, ax * (1 - ay)),
        (0, 1, (1 - ax) * ay),
        (1, 1, ax * ay),
    ):
        np.add.at(impulses, (np.minimum(y0 + dy, h - 1), np.minimum(x0 + dx, w - 1)), level * wgt)
    sigma = sigma_px * s
    pattern = cv2.GaussianBlur(impulses, (0, 0), sigma)
    pattern *= np.float32(2.0 * np.pi * sigma * sigma)
    pattern.setflags(write=False)
    return pattern


# --------------------------------------------------------------------------- rendering


def _padded(intrinsics: Intrinsics, pad: int) -> Intrinsics:
    return replace(intrinsics, width=intrinsics.width + pad, ppx=intrinsics.ppx + pad)


def _normals(
    x: np.ndarray, y: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit surface normals of a point map, facing the camera, from finite differences.

    Each direction takes the one-sided difference with the smaller depth step, so a pixel
    beside a depth edge gets its own surface's normal, not the edge's.
    """

    def diff(a: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
        fwd = np.zeros_like(a)
        bwd = np.zeros_like(a)
        if axis == 1:
            fwd[:, :-1] = a[:, 1:] - a[:, :-1]
            bwd[:, 1:] = fwd[:, :-1]
            fwd[:, -1] = bwd[:, -1]
            bwd[:, 0] = fwd[:, 0]
        else:
            fwd[:-1] = a[1:] - a[:-1]
            bwd[1:] = fwd[:-1]
            fwd[-1] = bwd[-1]
            bwd[0] = fwd[0]
        return fwd, bwd

    zf = np.where(np.isfinite(z), z, np.float32(1e6))
    tangents = []
    for axis in (1, 0):
        fz, bz = diff(zf, axis)
        use_fwd = np.abs(fz) <= np.abs(bz)
        tx, ty = (np.where(use_fwd, *diff(np.where(np.isfinite(a), a, 0), axis)) for a in (x, y))
        tangents.append((tx, ty, np.where(use_fwd, fz, bz)))
    (ux, uy, uz), (vx, vy, vz) = tangents
    nx = uy * vz - uz * vy
    ny = uz * vx - ux * vz
    nz = ux * vy - uy * vx
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    # Face the camera: n . p < 0 for a visible surface.
    sign = np.where(nx * x + ny * y + nz * z > 0, -1.0, 1.0).astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = sign / norm
    return nx * inv, ny * inv, nz * inv


def _lit(
    scene: Scene,
    projector_pose: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    pz: np.ndarray,
) -> np.ndarray:
    """Which points (projector frame, 1-D arrays) the projector sees: the ray from the
    projector toward each meets nothing before it."""
    proj_from_world = invert_pose(projector_pose)
    sx = px.astype(np.float64) / pz
    sy = py.astype(np.float64) / pz
    dd = sx * sx + sy * sy + 1.0
    first = np.full(pz.shape, np.inf)
    if scene.support is not None:
        t = scene.support.transformed(proj_from_world).intersect(Rays(sx, sy, 1.0, dd))
        np.minimum(first, t, out=first)
    for obj in scene.objects:
        moved = obj.transformed(proj_from_world)
        center, radius = moved.bounds()
        # Cull rays that pass wide of the object's bounding sphere or end before it.
        along = sx * center[0] + sy * center[1] + center[2]
        miss2 = float(center @ center) - along * along / dd
        near = (miss2 <= radius * radius) & (pz > center[2] - radius)
        idx = np.flatnonzero(near)
        if idx.size == 0:
            continue
        rays = Rays(sx[idx], sy[idx], 1.0, dd[idx])
        for part in moved.parts:
            first[idx] = np.minimum(first[idx], part.intersect(rays))
    return first >= pz - _SHADOW_TOL_M


def _radiance(
    scene: Scene,
    intrinsics: Intrinsics,
    camera_pose: np.ndarray,
    offset_x_m: float,
    rig: StereoRig,
    pattern_f: tuple[float, float],
) -> np.ndarray:
    """Image of one imager (``offset_x_m`` along the left imager's x), in units of the dot
    peak on a white fronto-parallel surface at the reference range, before the imager."""
    cv2 = import_cv2()
    pose = camera_pose @ make_pose(None, (offset_x_m, 0.0, 0.0))
    z = exact_depth(scene, intrinsics, pose, "float32")
    hit = np.isfinite(z)
    xs, ys = intrinsics.pixel_rays()
    zf = np.where(hit, z, np.float32(0.0))
    x = (xs * zf).astype(np.float32)
    y = (ys * zf).astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        nx, ny, nz = _normals(x, y, z)
    # Points relative to the projector (same orientation as the imagers).
    qx = x + np.float32(offset_x_m - rig.projector_x_m)
    out = np.zeros(z.shape, dtype=np.float32)
    idx = np.flatnonzero(hit)
    if idx.size == 0:
        return out
    px, py, pz = qx.reshape(-1)[idx], y.reshape(-1)[idx], z.reshape(-1)[idx]
    cx = x.reshape(-1)[idx]
    n = [c.reshape(-1)[idx] for c in (nx, ny, nz)]
    r2 = px * px + py * py + pz * pz
    # Lambert: cos between the normal and the direction to the projector.
    cos_p = -(n[0] * px + n[1] * py + n[2] * pz) / np.sqrt(r2)
    cos_p = np.clip(np.nan_to_num(cos_p), 0.0, 1.0)
    lit = _lit(scene, camera_pose @ make_pose(None, (rig.projector_x_m, 0.0, 0.0)), px, py, pz)
    pattern = _dot_pattern(
        pattern_f[0],
        pattern_f[1],
        rig.dot_density,
        rig.dot_sigma_px,
        tuple(rig.dot_brightness),
        rig.pattern_seed,
    )
    s = _PATTERN_OVERSAMPLE
    ph, pw = pattern.shape
    map_x = np.full(z.shape, -1.0, dtype=np.float32)
    map_y = np.full(z.shape, -1.0, dtype=np.float32)
    map_x.reshape(-1)[idx] = (px / pz) * (pattern_f[0] * s) + 0.5 * (pw - 1)
    map_y.reshape(-1)[idx] = (py / pz) * (pattern_f[1] * s) + 0.5 * (ph - 1)
    dots = cv2.remap(pattern, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    irradiance = dots.reshape(-1)[idx] * cos_p * (_REFERENCE_RANGE_M**2 / r2) * lit
    # Room light: diffuse, brighter on surfaces facing the viewer.
    view_cos = -(n[0] * cx + n[1] * py + n[2] * pz) / np.sqrt(cx * cx + py * py + pz * pz)
    irradiance += rig.ambient * (0.5 + 0.5 * np.clip(np.nan_to_num(view_cos), 0.0, 1.0))
    out.reshape(-1)[idx] = rig.albedo * irradiance
    return out


def _expose(radiance: np.ndarray, rig: StereoRig, rng: np.random.Generator) -> np.ndarray:
    """Optics blur, shot and read noise, 8-bit quantisation."""
    cv2 = import_cv2()
    signal = radiance * np.float32(rig.gain_dn)
    if rig.blur_sigma_px > 0:
        signal = cv2.GaussianBlur(signal, (0, 0), rig.blur_sigma_px)
    noise_sd = np.sqrt(signal / np.float32(rig.electrons_per_dn) + np.float32(rig.read_noise_dn**2))
    signal += noise_sd * rng.standard_normal(signal.shape, dtype=np.float32)
    return np.clip(np.rint(signal), 0, 255).astype(np.uint8)


def render_ir(
    scene: Scene,
    intrinsics: Intrinsics,
    camera_pose: np.ndarray,
    rng: np.random.Generator,
    rig: StereoRig = StereoRig(),
    pad: int = 0,
) -> IrPair:
    """Render the left and right IR images (uint8, ``(H, W + pad)``) of a scene.

    ``camera_pose`` is the world-from-left-imager transform (the depth frame's). rng draws the
    left image's noise, then the right's.
    """
    check_pose(camera_pose)
    wide = _padded(intrinsics, pad)
    k = rig.supersample
    if k > 1:
        # k x k samples per pixel, pixel centres kept: sample (i, j) of pixel (u, v) sits at
        # u + (i + 0.5) / k - 0.5.
        wide = replace(
            wide,
            width=wide.width * k,
            height=wide.height * k,
            fx=wide.fx * k,
            fy=wide.fy * k,
            ppx=(wide.ppx + 0.5) * k - 0.5,
            ppy=(wide.ppy + 0.5) * k - 0.5,
        )
    focal = (intrinsics.fx, intrinsics.fy)
    images = []
    for offset in (0.0, rig.baseline_m):
        radiance = _radiance(scene, wide, camera_pose, offset, rig, focal)
        if k > 1:
            radiance = radiance.reshape(radiance.shape[0] // k, k, -1, k).mean(axis=(1, 3))
        images.append(_expose(radiance, rig, rng))
    return IrPair(images[0], images[1], pad)


def match(pair: IrPair, matcher: Matcher = Matcher()) -> np.ndarray:
    """Disparity of the left image, int16 in 1/16 px (OpenCV's fixed point), <= 0 where the
    matcher found none; the pad cut off."""
    stereo = matcher.create()
    disparity = stereo.compute(pair.left, pair.right)
    if matcher.kind == "bm" and matcher.disp12_max_diff >= 0:
        disparity = _left_right_check(disparity, stereo, pair, matcher.disp12_max_diff)
    if matcher.min_texture > 0:
        cv2 = import_cv2()
        cap = matcher.pre_filter_cap
        gradient = np.abs(np.clip(cv2.Sobel(pair.left, cv2.CV_16S, 1, 0, ksize=3), -cap, cap))
        size = (matcher.block_size, matcher.block_size)
        texture = cv2.blur(gradient.astype(np.float32), size)
        disparity[texture < matcher.min_texture] = -16
    return disparity[:, pair.pad :]


def _left_right_check(disparity: np.ndarray, stereo, pair: IrPair, max_diff: int) -> np.ndarray:
    """Drop left disparities that the right image's own match (the mirrored images matched
    the same way) contradicts by more than ``max_diff`` px; a right pixel without a match
    contradicts nothing."""
    mirrored = stereo.compute(
        np.ascontiguousarray(pair.right[:, ::-1]), np.ascontiguousarray(pair.left[:, ::-1])
    )[:, ::-1]
    rows, cols = np.nonzero(disparity > 0)
    d = disparity[rows, cols]
    at_right = cols - (d.astype(np.int64) + 8) // 16
    inside = at_right >= 0
    back = np.full(d.shape, -16, dtype=np.int16)
    back[inside] = mirrored[rows[inside], at_right[inside]]
    bad = (back > 0) & (np.abs(back.astype(np.int32) - d) > 16 * max_diff)
    out = disparity.copy()
    out[rows[bad], cols[bad]] = -16
    return out


def disparity_to_depth(
    disparity16: np.ndarray, intrinsics: Intrinsics, baseline_m: float, left_band: bool = True
) -> np.ndarray:
    """Depth in depth units (uint16, 0 = hole) from a 1/16 px disparity: z = fx B / d.

    With ``left_band``, pixels whose match would fall left of the right imager's first column
    are holes, as on the device (its invalid band on the left).
    """
    d = disparity16.astype(np.float32) / np.float32(16.0)
    valid = d > 0
    if left_band:
        cols = np.arange(d.shape[1], dtype=np.float32)[None, :]
        valid &= cols - d >= 0
    with np.errstate(divide="ignore"):
        units = (intrinsics.fx * baseline_m / intrinsics.depth_scale) / d
    units = np.where(valid, np.rint(units), 0.0)
    return np.clip(units, 0, np.iinfo(np.uint16).max).astype(np.uint16)


@dataclass(frozen=True, kw_only=True)
class StereoSensor:
    """A rig and a matcher: renders D435-like depth frames by stereo matching."""

    rig: StereoRig = StereoRig()
    matcher: Matcher = Matcher()

    def render_pair(
        self,
        scene: Scene,
        intrinsics: Intrinsics,
        camera_pose: np.ndarray,
        rng: np.random.Generator,
    ) -> IrPair:
        return render_ir(
            scene, intrinsics, camera_pose, rng, self.rig, pad=self.matcher.num_disparities
        )

    def depth_from_pair(self, pair: IrPair, intrinsics: Intrinsics) -> np.ndarray:
        return disparity_to_depth(
            match(pair, self.matcher), intrinsics, self.rig.baseline_m, self.rig.left_band
        )

    def render_depth(
        self,
        scene: Scene,
        intrinsics: Intrinsics,
        camera_pose: np.ndarray,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """A depth frame (uint16 depth units, 0 = hole), like ``scene.render_depth``."""
        pair = self.render_pair(scene, intrinsics, camera_pose, rng)
        return self.depth_from_pair(pair, intrinsics)


def render_stereo_depth(
    scene: Scene,
    intrinsics: Intrinsics,
    camera_pose: np.ndarray,
    rng: np.random.Generator,
    sensor: StereoSensor = StereoSensor(),
) -> np.ndarray:
    """Drop-in for ``scene.render_depth``: the depth a stereo camera would match."""
    return sensor.render_depth(scene, intrinsics, camera_pose, rng)
