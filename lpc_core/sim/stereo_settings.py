"""The simulated stereo camera's settings: the sensor rig and the OpenCV matcher.

Kept apart from ``lpc_core.sim.stereo`` (the rendering and matching, numpy and OpenCV) so that
a process which only parses and passes on these settings, as ``lpc up``'s supervisor does,
loads neither: numpy alone is about 12 MB of every process's resident memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

MatcherKind = Literal["sgbm", "bm"]
MATCHERS: tuple[MatcherKind, ...] = ("sgbm", "bm")


def import_cv2():
    try:
        import cv2  # type: ignore[import-not-found]
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError(
            "the stereo camera needs OpenCV: pip install 'lpc[stereo]'", name="cv2"
        ) from exc
    return cv2


@dataclass(frozen=True, kw_only=True)
class StereoRig:
    """The sensor: imager pair, dot projector, optics and noise; every figure a parameter.

    ``dot_density`` is dots per pixel² of the depth image (a D435's few thousand dots over
    its field give about 0.05 at 424x240); ``dot_sigma_px`` the dots' Gaussian radius in
    image pixels. ``gain_dn`` is the 8-bit value of a dot's peak on a fronto-parallel white
    surface at 0.2 m (nearer is brighter by 1/r² and clips at 255). ``ambient`` is the
    irradiance of the room light relative to that dot peak. Noise: ``electrons_per_dn`` sets
    the shot noise (variance = DN / electrons_per_dn), ``read_noise_dn`` the read noise.
    """

    baseline_m: float = 0.05
    projector_x_m: float = 0.025
    dot_density: float = 0.06
    dot_sigma_px: float = 0.6
    dot_brightness: tuple[float, float] = (0.6, 1.0)
    pattern_seed: int = 0
    albedo: float = 0.8
    ambient: float = 0.08
    gain_dn: float = 320.0
    blur_sigma_px: float = 0.5
    electrons_per_dn: float = 10.0
    read_noise_dn: float = 1.0
    supersample: int = 1
    left_band: bool = True

    def __post_init__(self) -> None:
        for name in ("baseline_m", "dot_density", "dot_sigma_px", "gain_dn", "electrons_per_dn"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value}")
        for name in ("albedo", "ambient", "blur_sigma_px", "read_noise_dn"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a non-negative finite number, got {value}")
        if not 0.0 <= self.projector_x_m <= self.baseline_m:
            raise ValueError("projector_x_m must lie between the imagers, in [0, baseline_m]")
        if not 1 <= self.supersample <= 4:
            raise ValueError(f"supersample must be in [1, 4], got {self.supersample}")
        lo, hi = self.dot_brightness
        if not 0.0 < lo <= hi:
            raise ValueError(f"dot_brightness must be 0 < lo <= hi, got {self.dot_brightness}")


@dataclass(frozen=True, kw_only=True)
class Matcher:
    """An OpenCV stereo matcher and its settings (OpenCV's names and units).

    ``kind`` "sgbm" is semi-global block matching (``cv2.StereoSGBM``, smoothness penalties
    ``p1``, ``p2``: default 8 and 32 times the block's area); "bm" is plain block matching
    (``cv2.StereoBM``), noisier and without a smoothness term. ``uniqueness`` is the margin
    in percent by which the best cost must beat the second best; ``texture_threshold`` (BM
    only, OpenCV's own) drops windows whose summed pre-filtered response is below it.
    ``min_texture`` is the device's texture check, for both matchers: a window of the left
    image whose mean |x-gradient| (3x3 Sobel, clipped at ``pre_filter_cap``) is below it, in
    DN per pixel, gives no depth (sensor noise alone gives about 3); without it SGBM's
    smoothness carries a near surface's disparity far across dark, dotless background.
    ``speckle_window`` / ``speckle_range`` (px, for both) remove small disparity islands (0
    turns it off). ``disp12_max_diff`` is the left-right consistency check in px (-1: off).
    """

    kind: MatcherKind = "sgbm"
    block_size: int = 7
    num_disparities: int = 128
    uniqueness: int = 10
    texture_threshold: int = 10
    min_texture: float = 5.0
    speckle_window: int = 100
    speckle_range: int = 2
    disp12_max_diff: int = 1
    pre_filter_cap: int = 63
    p1: int | None = None
    p2: int | None = None
    sgbm_mode: Literal["sgbm", "hh", "3way"] = "sgbm"

    def __post_init__(self) -> None:
        if self.kind not in MATCHERS:
            raise ValueError(f"kind must be one of {MATCHERS}, got {self.kind!r}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd and positive, got {self.block_size}")
        if self.kind == "bm" and not 5 <= self.block_size <= 255:
            raise ValueError(f"block_size for bm must be in [5, 255], got {self.block_size}")
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ValueError(
                f"num_disparities must be a positive multiple of 16, got {self.num_disparities}"
            )
        if not 0 <= self.uniqueness <= 100:
            raise ValueError(f"uniqueness must be in [0, 100], got {self.uniqueness}")
        if not math.isfinite(self.min_texture) or self.min_texture < 0:
            raise ValueError(f"min_texture must be a non-negative number, got {self.min_texture}")
        if self.texture_threshold < 0 or self.speckle_window < 0 or self.speckle_range < 0:
            raise ValueError("texture_threshold, speckle_window and speckle_range must be >= 0")
        if not 1 <= self.pre_filter_cap <= 63:
            raise ValueError(f"pre_filter_cap must be in [1, 63], got {self.pre_filter_cap}")

    def create(self):
        """The configured ``cv2.StereoSGBM`` or ``cv2.StereoBM``."""
        cv2 = import_cv2()
        area = self.block_size * self.block_size
        if self.kind == "sgbm":
            modes = {
                "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
                "hh": cv2.STEREO_SGBM_MODE_HH,
                "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
            }
            return cv2.StereoSGBM.create(
                minDisparity=0,
                numDisparities=self.num_disparities,
                blockSize=self.block_size,
                P1=8 * area if self.p1 is None else self.p1,
                P2=32 * area if self.p2 is None else self.p2,
                disp12MaxDiff=self.disp12_max_diff,
                preFilterCap=self.pre_filter_cap,
                uniquenessRatio=self.uniqueness,
                speckleWindowSize=self.speckle_window,
                speckleRange=self.speckle_range,
                mode=modes[self.sgbm_mode],
            )
        bm = cv2.StereoBM.create(numDisparities=self.num_disparities, blockSize=self.block_size)
        bm.setPreFilterCap(self.pre_filter_cap)
        bm.setTextureThreshold(self.texture_threshold)
        bm.setUniquenessRatio(self.uniqueness)
        bm.setSpeckleWindowSize(self.speckle_window)
        # BM filters speckles on its 1/16 px output without scaling the range (SGBM scales it).
        bm.setSpeckleRange(16 * self.speckle_range)
        # OpenCV's own left-right check in StereoBM reads memory it has not set (a frame
        # matched twice can differ): ``match`` runs the check itself.
        bm.setDisp12MaxDiff(-1)
        return bm
