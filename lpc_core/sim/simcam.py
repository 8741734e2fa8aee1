"""The built-in simulated camera: the scripted timeline rendered as a D435-like sensor sees it.

A frame is a pure function of ``(seed, t_s, seq)``: the noise generator is seeded from the seed
and the frame's ``seq``, so a replay renders the same pixels. The depth comes from the noise
model (``scene.NoiseModel``, the default) or, given a ``StereoSensor``, from matching the two
IR images of a simulated active stereo camera (``lpc_core.sim.stereo``).
"""

from __future__ import annotations

import numpy as np

from lpc_core.perception.intrinsics import D435_424X240, Intrinsics
from lpc_core.sim.scene import NoiseModel, render_depth
from lpc_core.sim.stereo import StereoSensor
from lpc_core.sim.timeline import SimTimeline, default_timeline
from schemas import ObjectTruth


class SimCamera:
    def __init__(
        self,
        seed: int = 0,
        *,
        timeline: SimTimeline | None = None,
        intrinsics: Intrinsics = D435_424X240,
        noise: NoiseModel | None = None,
        sensor: StereoSensor | None = None,
    ) -> None:
        self.seed = seed
        self.timeline = timeline or default_timeline(seed=seed)
        self.intrinsics = intrinsics
        self.noise = noise or NoiseModel()
        self.sensor = sensor

    def frame(self, t_s: float, seq: int) -> tuple[np.ndarray, ObjectTruth | None]:
        """Depth (uint16, depth units) at ``t_s`` seconds into the session, and the truth of
        the object being aimed at (None between objects)."""
        sample = self.timeline.at(t_s)
        rng = np.random.default_rng([self.seed, seq])
        if self.sensor is None:
            depth = render_depth(sample.scene, self.intrinsics, sample.camera_pose, rng, self.noise)
        else:
            depth = self.sensor.render_depth(sample.scene, self.intrinsics, sample.camera_pose, rng)
        target = sample.target
        truth = None
        if target is not None:
            truth = ObjectTruth(
                name=target.name,
                shape=target.shape,
                grasp_width_mm=target.grasp_width_mm,
                wrist_angle_deg=target.wrist_angle_deg,
                pierced=target.pierced,
            )
        return depth, truth
