"""Pinhole intrinsics of the depth stream, with pyrealsense2's field names."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, kw_only=True)
class Intrinsics:
    """Depth camera intrinsics (pyrealsense2 names; distortion is ignored for depth).

    ``depth_scale`` is metres per depth unit (0.001 for the D435's default 1 mm unit).
    """

    width: int = 424
    height: int = 240
    fx: float = 213.0
    fy: float = 213.0
    ppx: float = 212.0
    ppy: float = 120.0
    model: str = "brown_conrady"
    coeffs: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))
    depth_scale: float = 0.001

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("fx", "fy", "depth_scale"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value}")

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-pixel ray slopes ``(x/z, y/z)``, each of shape ``(height, width)``."""
        u = (np.arange(self.width, dtype=np.float64) - self.ppx) / self.fx
        v = (np.arange(self.height, dtype=np.float64) - self.ppy) / self.fy
        return np.broadcast_to(u, (self.height, self.width)), np.broadcast_to(
            v[:, None], (self.height, self.width)
        )


D435_424X240 = Intrinsics()
