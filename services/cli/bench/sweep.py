"""``lpc bench sweep``: both methods over many settings of the simulated stereo camera.

Issue 15 asks that the method not be tuned to one matcher or one setting. The sweep renders the
same views through each named setting (``SETTINGS``), reconstructs them with the four-line and
the full-cloud methods, and prints one row per setting: width MAE per shape (the per-frame shape
accuracy beside it where it is below 100 %), the wrist angle's MAE and the irregular objects
handled. Three groups: ``tuning``, the settings the rules were studied on; ``untuned``,
settings no rule was studied on when they were added (a stand-in for the unseen sensor that
judges the issue: another baseline, smoothness, supersampling, optics, no left-right check,
blocks 3 and 11, no texture check, other SGBM modes, another dot pattern, a weaker signal); and
``fresh``, combinations added at the end of a round and never looked at while its rules were
written, so that the round's before -> after on them is an honest held-out figure.

``--json FILE`` keeps the figures; ``--against FILE`` prints each cell as ``before -> after``
where it differs from that earlier run (the same settings, suites and frames), so that a change
to the method is measured on every setting at once.

    lpc bench sweep --cache /tmp/lpc-frames --json before.json
    lpc bench sweep --cache /tmp/lpc-frames --against before.json --objects
    lpc bench sweep --group untuned --setting sgbm7 --suite functional
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lpc_core.sim.stereo_settings import Matcher, StereoRig

GROUPS = ("tuning", "untuned", "fresh")
SUITES = ("functional", "irregular", "rotation")
SHAPE_SUITES = ("functional", "rotation")
METHODS = ("laser", "cloud")
SHAPES = ("sphere", "cylinder", "cuboid")


@dataclass(frozen=True)
class Setting:
    """A named stereo camera: the rig's and the matcher's fields that differ from the defaults.
    ``smoothness`` scales SGBM's P1 and P2 from OpenCV's usual 8 and 32 times the block's area."""

    group: str
    label: str
    rig: dict[str, Any] = field(default_factory=dict)
    matcher: dict[str, Any] = field(default_factory=dict)
    smoothness: tuple[float, float] | None = None

    def sensor(self):  # -> StereoSensor (imported late: it needs OpenCV)
        from lpc_core.sim.stereo import StereoSensor

        matcher = dict(self.matcher)
        if self.smoothness is not None:
            area = matcher.get("block_size", Matcher().block_size) ** 2
            matcher["p1"] = round(8 * area * self.smoothness[0])
            matcher["p2"] = round(32 * area * self.smoothness[1])
        return StereoSensor(rig=StereoRig(**self.rig), matcher=Matcher(**matcher))


SETTINGS: dict[str, Setting] = {
    "sgbm5": Setting("tuning", "SGBM 5", matcher={"block_size": 5}),
    "sgbm7": Setting("tuning", "SGBM 7"),
    "sgbm9": Setting("tuning", "SGBM 9", matcher={"block_size": 9}),
    "sgbm7-u5": Setting("tuning", "SGBM 7, uniqueness 5", matcher={"uniqueness": 5}),
    "sgbm7-d04": Setting("tuning", "SGBM 7, 0.04 dots/px²", rig={"dot_density": 0.04}),
    "bm5": Setting("tuning", "BM 5", matcher={"kind": "bm", "block_size": 5}),
    "bm7": Setting("tuning", "BM 7", matcher={"kind": "bm", "block_size": 7}),
    "bm9": Setting("tuning", "BM 9", matcher={"kind": "bm", "block_size": 9}),
    "base55": Setting(
        "untuned", "SGBM 7, 55 mm baseline", rig={"baseline_m": 0.055, "projector_x_m": 0.0275}
    ),
    "p2x2": Setting("untuned", "SGBM 7, P2 x 2", smoothness=(1.0, 2.0)),
    "p1p2x2": Setting("untuned", "SGBM 7, P1 and P2 x 2", smoothness=(2.0, 2.0)),
    "p1x3p2x6": Setting("untuned", "SGBM 7, P1 x 3, P2 x 6", smoothness=(3.0, 6.0)),
    "super2": Setting("untuned", "SGBM 7, IR 2x supersampled", rig={"supersample": 2}),
    "blur": Setting(
        "untuned",
        "SGBM 7, blurrier optics and dots",
        rig={"blur_sigma_px": 1.0, "dot_sigma_px": 0.9},
    ),
    "nolr": Setting(
        "untuned",
        "SGBM 7, no left-right check or speckle filter",
        matcher={"disp12_max_diff": -1, "speckle_window": 0},
    ),
    "sgbm3": Setting("untuned", "SGBM 3", matcher={"block_size": 3}),
    "sgbm11": Setting("untuned", "SGBM 11", matcher={"block_size": 11}),
    "bm11": Setting("untuned", "BM 11", matcher={"kind": "bm", "block_size": 11}),
    "notex": Setting("untuned", "SGBM 7, no texture check", matcher={"min_texture": 0.0}),
    "cvsample": Setting(
        "untuned",
        "SGBM 7, OpenCV sample's P1 and P2 (x 3), speckle range 32",
        matcher={"speckle_range": 32},
        smoothness=(3.0, 3.0),
    ),
    "3way": Setting("untuned", "SGBM 7, 3-way mode", matcher={"sgbm_mode": "3way"}),
    "hh": Setting("untuned", "SGBM 7, 8-path (HH) mode", matcher={"sgbm_mode": "hh"}),
    "pattern1": Setting("untuned", "SGBM 7, another projector's dots", rig={"pattern_seed": 1}),
    "dim": Setting(
        "untuned",
        "SGBM 7, half the signal, more read noise",
        rig={"gain_dn": 160.0, "read_noise_dn": 2.0},
    ),
    # Held out from every helper of stop 32 (then its "fresh" group); studied from stop 33.
    "sgbm5-u15": Setting(
        "untuned",
        "SGBM 5, uniqueness 15, P1 x 2, P2 x 4",
        matcher={"block_size": 5, "uniqueness": 15},
        smoothness=(2.0, 4.0),
    ),
    "sgbm9-3way": Setting(
        "untuned",
        "SGBM 9, 3-way mode, P2 x 2",
        matcher={"block_size": 9, "sgbm_mode": "3way"},
        smoothness=(1.0, 2.0),
    ),
    "pattern2": Setting(
        "untuned",
        "SGBM 7, a third dot pattern, 0.05 dots/px², blurrier optics",
        rig={"pattern_seed": 2, "dot_density": 0.05, "blur_sigma_px": 0.8},
    ),
    "base45": Setting(
        "untuned",
        "SGBM 7, 45 mm baseline, 70 % of the signal, read noise 1.5",
        rig={"baseline_m": 0.045, "projector_x_m": 0.0225, "gain_dn": 220.0, "read_noise_dn": 1.5},
    ),
    "bm7-u5": Setting(
        "untuned",
        "BM 7, uniqueness 5, texture threshold 20",
        matcher={"kind": "bm", "block_size": 7, "uniqueness": 5, "texture_threshold": 20},
    ),
    # Held out from every helper of stop 33 (then its "fresh" group); studied from stop 34.
    "light4": Setting(
        "untuned",
        "SGBM 7, four times the room light, albedo 0.6, a fourth dot pattern",
        rig={"ambient": 0.32, "albedo": 0.6, "pattern_seed": 3},
    ),
    "hh5": Setting(
        "untuned",
        "SGBM 5, HH mode, P1 x 1.5, P2 x 3, uniqueness 12, 0.05 dots/px²",
        rig={"dot_density": 0.05},
        matcher={"block_size": 5, "sgbm_mode": "hh", "uniqueness": 12},
        smoothness=(1.5, 3.0),
    ),
    "soft9": Setting(
        "untuned",
        "SGBM 9, P1 and P2 / 2, uniqueness 5, speckle range 16, texture check 3",
        matcher={"block_size": 9, "uniqueness": 5, "speckle_range": 16, "min_texture": 3.0},
        smoothness=(0.5, 0.5),
    ),
    "bm9-p4": Setting(
        "untuned",
        "BM 9, uniqueness 15, texture threshold 5, a fifth dot pattern, optics 0.7 px",
        rig={"pattern_seed": 4, "blur_sigma_px": 0.7},
        matcher={"kind": "bm", "block_size": 9, "uniqueness": 15, "texture_threshold": 5},
    ),
    "shot": Setting(
        "untuned",
        "SGBM 7, 2.5 times the shot noise, 80 % of the signal, dots 0.8 px, left-right 2 px",
        rig={"electrons_per_dn": 4.0, "gain_dn": 260.0, "dot_sigma_px": 0.8},
        matcher={"disp12_max_diff": 2},
    ),
    # Held out from every helper of stop 34 (then its "fresh" group); studied from stop 35.
    "sparse35": Setting(
        "untuned",
        "SGBM 7, 0.035 dots/px² of uneven brightness, speckle window 50 and range 4",
        rig={"dot_density": 0.035, "dot_brightness": (0.3, 1.0), "pattern_seed": 5},
        matcher={"speckle_window": 50, "speckle_range": 4},
    ),
    "bm5-t30": Setting(
        "untuned",
        "BM 5, texture threshold 30, uniqueness 8, optics 0.6 px, a sixth dot pattern",
        rig={"pattern_seed": 6, "blur_sigma_px": 0.6},
        matcher={"kind": "bm", "block_size": 5, "texture_threshold": 30, "uniqueness": 8},
    ),
    "base40": Setting(
        "untuned",
        "SGBM 7, 40 mm baseline, projector off-centre, twice the room light",
        rig={"baseline_m": 0.04, "projector_x_m": 0.01, "ambient": 0.16},
    ),
    "3way5-ss": Setting(
        "untuned",
        "SGBM 5, 3-way mode, P1 and P2 x 2, IR 2x supersampled, read noise 1.5",
        rig={"supersample": 2, "read_noise_dn": 1.5},
        matcher={"block_size": 5, "sgbm_mode": "3way"},
        smoothness=(2.0, 2.0),
    ),
    "hh9-nolr": Setting(
        "untuned",
        "SGBM 9, HH mode, uniqueness 8, no left-right check, dots 0.5 px, albedo 0.5",
        rig={"dot_sigma_px": 0.5, "albedo": 0.5},
        matcher={"block_size": 9, "sgbm_mode": "hh", "uniqueness": 8, "disp12_max_diff": -1},
    ),
    # Held out from every helper of stop 35 (then its "fresh" group); studied from stop 36.
    "bm7-t20": Setting(
        "untuned",
        "BM 7, uniqueness 12, texture threshold 20, prefilter cap 31, a seventh dot pattern",
        rig={"pattern_seed": 7},
        matcher={
            "kind": "bm",
            "block_size": 7,
            "uniqueness": 12,
            "texture_threshold": 20,
            "pre_filter_cap": 31,
        },
    ),
    "proj35": Setting(
        "untuned",
        "SGBM 7, projector 35 mm from the left imager, dots 0.7 px, three times the room light",
        rig={"projector_x_m": 0.035, "dot_sigma_px": 0.7, "ambient": 0.24},
    ),
    "dense5": Setting(
        "untuned",
        "SGBM 5, 0.08 dots/px² of even brightness, uniqueness 15, speckle window 200, range 1",
        rig={"dot_density": 0.08, "dot_brightness": (0.8, 1.0)},
        matcher={"block_size": 5, "uniqueness": 15, "speckle_window": 200, "speckle_range": 1},
    ),
    "hh7-p2x4": Setting(
        "untuned",
        "SGBM 7, HH mode, P1 / 2, P2 x 4, 1.7 times the shot noise, optics 0.8 px",
        rig={"electrons_per_dn": 6.0, "blur_sigma_px": 0.8},
        matcher={"sgbm_mode": "hh"},
        smoothness=(0.5, 4.0),
    ),
    "3way9-dark": Setting(
        "untuned",
        "SGBM 9, 3-way mode, albedo 0.4, read noise 2, an eighth dot pattern, texture check 8",
        rig={"albedo": 0.4, "read_noise_dn": 2.0, "pattern_seed": 8},
        matcher={"block_size": 9, "sgbm_mode": "3way", "min_texture": 8.0},
    ),
    # Held out from every helper of stop 36 (then its "fresh" group); studied from stop 37.
    "bm9-s150": Setting(
        "untuned",
        "BM 9, uniqueness 10, speckle window 150 and range 1, 0.045 dots/px², a ninth pattern",
        rig={"dot_density": 0.045, "pattern_seed": 9},
        matcher={"kind": "bm", "block_size": 9, "speckle_window": 150, "speckle_range": 1},
    ),
    "base60": Setting(
        "untuned",
        "SGBM 7, 60 mm baseline, projector 20 mm from the left imager, albedo 0.65",
        rig={"baseline_m": 0.06, "projector_x_m": 0.02, "albedo": 0.65},
    ),
    "hh5-dim": Setting(
        "untuned",
        "SGBM 5, HH mode, dots 0.45 px, 60 % of the signal, read noise 2.5",
        rig={"dot_sigma_px": 0.45, "gain_dn": 190.0, "read_noise_dn": 2.5},
        matcher={"block_size": 5, "sgbm_mode": "hh"},
    ),
    "p2x3-lr3": Setting(
        "untuned",
        "SGBM 9, P2 x 3, uniqueness 5, left-right 3 px, 2.5 times the room light",
        rig={"ambient": 0.2},
        matcher={"block_size": 9, "uniqueness": 5, "disp12_max_diff": 3},
        smoothness=(1.0, 3.0),
    ),
    "3way7-shot": Setting(
        "untuned",
        "SGBM 7, 3-way, IR 2x supersampled, 0.03 dots/px², twice the shot noise, a tenth pattern",
        rig={"supersample": 2, "dot_density": 0.03, "electrons_per_dn": 5.0, "pattern_seed": 10},
        matcher={"sgbm_mode": "3way"},
    ),
    # Held out from every helper of stop 37 (then its "fresh" group); studied from stop 38.
    "bm5-c45": Setting(
        "untuned",
        "BM 5, uniqueness 8, texture threshold 5, prefilter cap 45, 0.055 dots/px², "
        "optics 0.65 px, an eleventh pattern",
        rig={"dot_density": 0.055, "blur_sigma_px": 0.65, "pattern_seed": 11},
        matcher={
            "kind": "bm",
            "block_size": 5,
            "uniqueness": 8,
            "texture_threshold": 5,
            "pre_filter_cap": 45,
        },
    ),
    "proj15": Setting(
        "untuned",
        "SGBM 7, projector 15 mm from the left imager, dots 0.55 px, 1.25 times the shot noise, "
        "read noise 1.5, 1.5 times the room light",
        rig={
            "projector_x_m": 0.015,
            "dot_sigma_px": 0.55,
            "electrons_per_dn": 8.0,
            "read_noise_dn": 1.5,
            "ambient": 0.12,
        },
    ),
    "3way5-p15": Setting(
        "untuned",
        "SGBM 5, 3-way mode, P1 and P2 x 1.5, speckle window 50, a twelfth pattern",
        rig={"pattern_seed": 12},
        matcher={"block_size": 5, "sgbm_mode": "3way", "speckle_window": 50},
        smoothness=(1.5, 1.5),
    ),
    "hh9-uneven": Setting(
        "untuned",
        "SGBM 9, HH mode, albedo 0.55, 0.05 dots/px² of uneven brightness, uniqueness 12",
        rig={"albedo": 0.55, "dot_density": 0.05, "dot_brightness": (0.4, 1.0)},
        matcher={"block_size": 9, "sgbm_mode": "hh", "uniqueness": 12},
    ),
    "ss45": Setting(
        "untuned",
        "SGBM 7, 45 mm baseline, IR 2x supersampled, texture check 3, left-right 2 px, "
        "uniqueness 12",
        rig={"baseline_m": 0.045, "supersample": 2},
        matcher={"min_texture": 3.0, "disp12_max_diff": 2, "uniqueness": 12},
    ),
    # Held out from every helper of stop 38 (then its "fresh" group); studied from stop 39.
    "bm7-w": Setting(
        "untuned",
        "BM 7, uniqueness 12, texture threshold 8, speckle window 80, 0.07 dots/px² of "
        "0.7 px, a thirteenth pattern",
        rig={"dot_density": 0.07, "dot_sigma_px": 0.7, "pattern_seed": 13},
        matcher={
            "kind": "bm",
            "block_size": 7,
            "uniqueness": 12,
            "texture_threshold": 8,
            "speckle_window": 80,
        },
    ),
    "p1w-shot": Setting(
        "untuned",
        "SGBM 7, P1 x 0.75 and P2 x 2, 1.7 times the shot noise, a fourteenth pattern",
        rig={"electrons_per_dn": 6.0, "pattern_seed": 14},
        smoothness=(0.75, 2.0),
    ),
    "b52-p35": Setting(
        "untuned",
        "SGBM 9, uniqueness 8, 52 mm baseline, projector 35 mm from the left imager, "
        "optics 0.6 px, albedo 0.7, 1.25 times the room light",
        rig={
            "baseline_m": 0.052,
            "projector_x_m": 0.035,
            "blur_sigma_px": 0.6,
            "albedo": 0.7,
            "ambient": 0.1,
        },
        matcher={"block_size": 9, "uniqueness": 8},
    ),
    "hh7-x3": Setting(
        "untuned",
        "SGBM 7, HH mode, IR 3x supersampled, 0.04 dots/px² of brightness 0.5-1, "
        "a fifteenth pattern",
        rig={
            "supersample": 3,
            "dot_density": 0.04,
            "dot_brightness": (0.5, 1.0),
            "pattern_seed": 15,
        },
        matcher={"sgbm_mode": "hh"},
    ),
    "3way9-g": Setting(
        "untuned",
        "SGBM 9, 3-way mode, texture check 6, speckle range 1, 80 % of the signal, read noise 2",
        rig={"gain_dn": 260.0, "read_noise_dn": 2.0},
        matcher={
            "block_size": 9,
            "sgbm_mode": "3way",
            "min_texture": 6.0,
            "speckle_range": 1,
        },
    ),
    # Held out from every helper of stop 39 (then its "fresh" group); studied from stop 40.
    "bm9-c25": Setting(
        "untuned",
        "BM 9, uniqueness 10, texture threshold 12, prefilter cap 25, 0.045 dots/px², "
        "a sixteenth pattern",
        rig={"dot_density": 0.045, "pattern_seed": 16},
        matcher={
            "kind": "bm",
            "block_size": 9,
            "uniqueness": 10,
            "texture_threshold": 12,
            "pre_filter_cap": 25,
        },
    ),
    "sg5-s150": Setting(
        "untuned",
        "SGBM 5, P1 x 0.5 and P2 x 1.5, uniqueness 15, speckle window 150 of range 1, "
        "a seventeenth pattern",
        rig={"pattern_seed": 17},
        matcher={"block_size": 5, "uniqueness": 15, "speckle_window": 150, "speckle_range": 1},
        smoothness=(0.5, 1.5),
    ),
    "b48-p10": Setting(
        "untuned",
        "SGBM 7, 48 mm baseline, projector 10 mm from the left imager, albedo 0.6, "
        "optics 0.55 px, an eighteenth pattern",
        rig={
            "baseline_m": 0.048,
            "projector_x_m": 0.01,
            "albedo": 0.6,
            "blur_sigma_px": 0.55,
            "pattern_seed": 18,
        },
    ),
    "hh5-x2": Setting(
        "untuned",
        "SGBM 5, HH mode, IR 2x supersampled, 0.065 dots/px² of 0.5 px, 1.4 times the shot "
        "noise, read noise 1.8",
        rig={
            "supersample": 2,
            "dot_density": 0.065,
            "dot_sigma_px": 0.5,
            "electrons_per_dn": 7.0,
            "read_noise_dn": 1.8,
        },
        matcher={"block_size": 5, "sgbm_mode": "hh"},
    ),
    "3way7-a": Setting(
        "untuned",
        "SGBM 7, 3-way mode, uniqueness 6, left-right 2 px, 1.75 times the room light, "
        "dots of brightness 0.7-1, 75 % of the signal, a nineteenth pattern",
        rig={
            "ambient": 0.14,
            "dot_brightness": (0.7, 1.0),
            "gain_dn": 240.0,
            "pattern_seed": 19,
        },
        matcher={"sgbm_mode": "3way", "uniqueness": 6, "disp12_max_diff": 2},
    ),
    # Held out from every helper of stop 40 (then its "fresh" group); studied from stop 41.
    "bm7-t6": Setting(
        "untuned",
        "BM 7, uniqueness 8, texture threshold 6, prefilter cap 45, speckle window 60 of "
        "range 3, 0.055 dots/px² of 0.65 px, a twentieth pattern",
        rig={"dot_density": 0.055, "dot_sigma_px": 0.65, "pattern_seed": 20},
        matcher={
            "kind": "bm",
            "block_size": 7,
            "uniqueness": 8,
            "texture_threshold": 6,
            "pre_filter_cap": 45,
            "speckle_window": 60,
            "speckle_range": 3,
        },
    ),
    "sg9-w": Setting(
        "untuned",
        "SGBM 9, P1 x 1.25 and P2 x 2.5, uniqueness 12, left-right 3 px, dots of brightness "
        "0.5-0.9, a twenty-first pattern",
        rig={"dot_brightness": (0.5, 0.9), "pattern_seed": 21},
        matcher={"block_size": 9, "uniqueness": 12, "disp12_max_diff": 3},
        smoothness=(1.25, 2.5),
    ),
    "b56-p40": Setting(
        "untuned",
        "SGBM 7, 56 mm baseline, projector 40 mm from the left imager, optics 0.7 px, "
        "1.4 times the room light, 1.25 times the shot noise, a twenty-second pattern",
        rig={
            "baseline_m": 0.056,
            "projector_x_m": 0.04,
            "blur_sigma_px": 0.7,
            "ambient": 0.11,
            "electrons_per_dn": 8.0,
            "pattern_seed": 22,
        },
    ),
    "hh7-d": Setting(
        "untuned",
        "SGBM 7, HH mode, albedo 0.65, 87 % of the signal, read noise 1.5, texture check 4, "
        "a twenty-third pattern",
        rig={"albedo": 0.65, "gain_dn": 280.0, "read_noise_dn": 1.5, "pattern_seed": 23},
        matcher={"sgbm_mode": "hh", "min_texture": 4.0},
    ),
    "3way5-x3": Setting(
        "untuned",
        "SGBM 5, 3-way mode, IR 3x supersampled, 0.05 dots/px² of 0.8 px, uniqueness 9, "
        "speckle window 120, a twenty-fourth pattern",
        rig={"supersample": 3, "dot_density": 0.05, "dot_sigma_px": 0.8, "pattern_seed": 24},
        matcher={"block_size": 5, "sgbm_mode": "3way", "uniqueness": 9, "speckle_window": 120},
    ),
    # Held out from every helper of stop 41 (then its "fresh" group); studied from stop 42.
    "bm5-t15": Setting(
        "untuned",
        "BM 5, uniqueness 12, texture threshold 15, prefilter cap 35, optics 0.6 px, "
        "a twenty-fifth pattern",
        rig={"blur_sigma_px": 0.6, "pattern_seed": 25},
        matcher={
            "kind": "bm",
            "block_size": 5,
            "uniqueness": 12,
            "texture_threshold": 15,
            "pre_filter_cap": 35,
        },
    ),
    "sg7-p4": Setting(
        "untuned",
        "SGBM 7, P1 x 0.75 and P2 x 4, uniqueness 7, speckle window 80 of range 2, "
        "a twenty-sixth pattern",
        rig={"pattern_seed": 26},
        matcher={"uniqueness": 7, "speckle_window": 80},
        smoothness=(0.75, 4.0),
    ),
    "b42-p30": Setting(
        "untuned",
        "SGBM 9, 42 mm baseline, projector 30 mm from the left imager, albedo 0.7, "
        "read noise 1.3, a twenty-seventh pattern",
        rig={
            "baseline_m": 0.042,
            "projector_x_m": 0.03,
            "albedo": 0.7,
            "read_noise_dn": 1.3,
            "pattern_seed": 27,
        },
        matcher={"block_size": 9},
    ),
    "hh9-s2": Setting(
        "untuned",
        "SGBM 9, HH mode, IR 2x supersampled, 0.045 dots/px² of 0.7 px, left-right 2 px, "
        "a twenty-eighth pattern",
        rig={"supersample": 2, "dot_density": 0.045, "dot_sigma_px": 0.7, "pattern_seed": 28},
        matcher={"block_size": 9, "sgbm_mode": "hh", "disp12_max_diff": 2},
    ),
    "3way7-l2": Setting(
        "untuned",
        "SGBM 7, 3-way mode, twice the room light, 1.7 times the shot noise, uniqueness 11, "
        "texture check 5.5, a twenty-ninth pattern",
        rig={"ambient": 0.16, "electrons_per_dn": 6.0, "pattern_seed": 29},
        matcher={"sgbm_mode": "3way", "uniqueness": 11, "min_texture": 5.5},
    ),
    # Held out from every helper of stop 42 (then its "fresh" group); studied from stop 43.
    "bm9-t8": Setting(
        "untuned",
        "BM 9, uniqueness 10, texture threshold 8, prefilter cap 55, "
        "optics 0.55 px, a thirtieth pattern",
        rig={"blur_sigma_px": 0.55, "pattern_seed": 30},
        matcher={
            "kind": "bm",
            "block_size": 9,
            "uniqueness": 10,
            "texture_threshold": 8,
            "pre_filter_cap": 55,
        },
    ),
    "sg5-x2": Setting(
        "untuned",
        "SGBM 5, IR 2x supersampled, P1 and P2 x 1.5, left-right 2 px, 0.065 dots/px², "
        "a thirty-first pattern",
        rig={"supersample": 2, "dot_density": 0.065, "pattern_seed": 31},
        matcher={"block_size": 5, "disp12_max_diff": 2},
        smoothness=(1.5, 1.5),
    ),
    "b47-p35": Setting(
        "untuned",
        "SGBM 7, 47 mm baseline, projector 35 mm from the left imager, 1.6 times the room "
        "light, 81 % of the signal, a thirty-second pattern",
        rig={
            "baseline_m": 0.047,
            "projector_x_m": 0.035,
            "ambient": 0.13,
            "gain_dn": 260.0,
            "pattern_seed": 32,
        },
    ),
    "hh5-w": Setting(
        "untuned",
        "SGBM 5, HH mode, albedo 0.75, uniqueness 8, speckle window 60, dots of brightness "
        "0.45-1.0, a thirty-third pattern",
        rig={"albedo": 0.75, "dot_brightness": (0.45, 1.0), "pattern_seed": 33},
        matcher={"block_size": 5, "sgbm_mode": "hh", "uniqueness": 8, "speckle_window": 60},
    ),
    "3way9-x3": Setting(
        "untuned",
        "SGBM 9, 3-way mode, IR 3x supersampled, 0.04 dots/px² of 0.75 px, 1.4 times the shot "
        "noise, texture check 4.5, a thirty-fourth pattern",
        rig={
            "supersample": 3,
            "dot_density": 0.04,
            "dot_sigma_px": 0.75,
            "electrons_per_dn": 7.0,
            "pattern_seed": 34,
        },
        matcher={"block_size": 9, "sgbm_mode": "3way", "min_texture": 4.5},
    ),
    # Held out from every helper of stop 43 (then its "fresh" group); studied from stop 44.
    "bm7-s120": Setting(
        "untuned",
        "BM 7, uniqueness 8, texture threshold 12, prefilter cap 45, speckle window 120, "
        "0.05 dots/px², a thirty-fifth pattern",
        rig={"dot_density": 0.05, "pattern_seed": 35},
        matcher={
            "kind": "bm",
            "block_size": 7,
            "uniqueness": 8,
            "texture_threshold": 12,
            "pre_filter_cap": 45,
            "speckle_window": 120,
        },
    ),
    "hh9-l3": Setting(
        "untuned",
        "SGBM 9, HH mode, uniqueness 12, left-right 3 px, 75 % of the signal, "
        "a thirty-sixth pattern",
        rig={"gain_dn": 240.0, "pattern_seed": 36},
        matcher={"block_size": 9, "sgbm_mode": "hh", "uniqueness": 12, "disp12_max_diff": 3},
    ),
    "b53-p20": Setting(
        "untuned",
        "SGBM 5, 53 mm baseline, projector 20 mm from the left imager, albedo 0.7, "
        "read noise 1.5, a thirty-seventh pattern",
        rig={
            "baseline_m": 0.053,
            "projector_x_m": 0.02,
            "albedo": 0.7,
            "read_noise_dn": 1.5,
            "pattern_seed": 37,
        },
        matcher={"block_size": 5},
    ),
    "hh7-b8": Setting(
        "untuned",
        "SGBM 7, HH mode, optics 0.8 px, dots of 0.8 px, 1.5 times the room light, "
        "a thirty-eighth pattern",
        rig={"blur_sigma_px": 0.8, "dot_sigma_px": 0.8, "ambient": 0.12, "pattern_seed": 38},
        matcher={"sgbm_mode": "hh"},
    ),
    "3way5-d75": Setting(
        "untuned",
        "SGBM 5, 3-way mode, 0.075 dots/px² of 0.55 px and brightness 0.5-1.0, 1.3 times the "
        "shot noise, uniqueness 6, a thirty-ninth pattern",
        rig={
            "dot_density": 0.075,
            "dot_sigma_px": 0.55,
            "dot_brightness": (0.5, 1.0),
            "electrons_per_dn": 7.7,
            "pattern_seed": 39,
        },
        matcher={"block_size": 5, "sgbm_mode": "3way", "uniqueness": 6},
    ),
    # Held out from every helper of stop 44: only the lead's before -> after runs on them.
    "fresh-bm9w": Setting(
        "fresh",
        "BM 9, uniqueness 6, texture threshold 10, prefilter cap 40, speckle window 100 and "
        "range 2, 0.06 dots/px² of 0.75 px, a fortieth pattern",
        rig={"dot_density": 0.06, "dot_sigma_px": 0.75, "pattern_seed": 40},
        matcher={
            "kind": "bm",
            "block_size": 9,
            "uniqueness": 6,
            "texture_threshold": 10,
            "pre_filter_cap": 40,
            "speckle_window": 100,
            "speckle_range": 2,
        },
    ),
    "fresh-sg7m": Setting(
        "fresh",
        "SGBM 7, P1 x 1.25 and P2 x 3, uniqueness 9, albedo 0.8, read noise 1.8, "
        "a forty-first pattern",
        rig={"albedo": 0.8, "read_noise_dn": 1.8, "pattern_seed": 41},
        matcher={"uniqueness": 9},
        smoothness=(1.25, 3.0),
    ),
    "fresh-b58": Setting(
        "fresh",
        "SGBM 7, 58 mm baseline, projector 45 mm from the left imager, 1.1 times the room "
        "light, 72 % of the signal, a forty-second pattern",
        rig={
            "baseline_m": 0.058,
            "projector_x_m": 0.045,
            "ambient": 0.09,
            "gain_dn": 230.0,
            "pattern_seed": 42,
        },
    ),
    "fresh-hh5s": Setting(
        "fresh",
        "SGBM 5, HH mode, uniqueness 10, left-right 2 px, speckle window 100, 0.035 dots/px² "
        "of 0.6 px, read noise 2.2, a forty-third pattern",
        rig={
            "dot_density": 0.035,
            "dot_sigma_px": 0.6,
            "read_noise_dn": 2.2,
            "pattern_seed": 43,
        },
        matcher={
            "block_size": 5,
            "sgbm_mode": "hh",
            "uniqueness": 10,
            "disp12_max_diff": 2,
            "speckle_window": 100,
        },
    ),
    "fresh-3way11": Setting(
        "fresh",
        "SGBM 11, 3-way mode, uniqueness 7, albedo 0.6, optics 0.75 px, a forty-fourth pattern",
        rig={"albedo": 0.6, "blur_sigma_px": 0.75, "pattern_seed": 44},
        matcher={"block_size": 11, "sgbm_mode": "3way", "uniqueness": 7},
    ),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--group",
        action="append",
        choices=(*GROUPS, "all"),
        help="settings to run, repeatable: tuning (studied), untuned (never studied when added), "
        "fresh (held out from the last round) or all "
        "(default: tuning)",
    )
    parser.add_argument(
        "--setting",
        action="append",
        metavar="NAME",
        help=f"one setting, repeatable (instead of --group): {', '.join(SETTINGS)}",
    )
    parser.add_argument(
        "--suite",
        action="append",
        choices=SUITES,
        help="suite, repeatable (default: functional and irregular)",
    )
    parser.add_argument("--trials", type=int, default=2, help="trials per object (default 2)")
    parser.add_argument("--frames", type=int, default=5, help="frames per trial (default 5)")
    parser.add_argument("--seed", type=int, default=0, help="seed of poses and noise")
    parser.add_argument(
        "--object", action="append", metavar="NAME", help="only this object, repeatable"
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="keep the rendered frames in DIR and read them back on later runs (a stereo "
        "frame costs about 100 ms to render; the sweep renders thousands)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=os.cpu_count() or 1,
        help="processes, one (setting, suite) each (default: the CPUs)",
    )
    parser.add_argument("--json", type=Path, metavar="FILE", help="write the figures to FILE")
    parser.add_argument(
        "--against",
        type=Path,
        metavar="FILE",
        help="an earlier --json: print each figure as before -> after where it differs",
    )
    parser.add_argument(
        "--objects", action="store_true", help="also the width and angle MAE per object"
    )


def _setting_names(args: argparse.Namespace) -> list[str]:
    if args.setting:
        unknown = [n for n in args.setting if n not in SETTINGS]
        if unknown:
            known = ", ".join(SETTINGS)
            raise ValueError(f"unknown --setting {', '.join(unknown)}; known: {known}")
        return list(dict.fromkeys(args.setting))
    groups = args.group or ["tuning"]
    if "all" in groups:
        groups = list(GROUPS)
    return [n for n, s in SETTINGS.items() if s.group in groups]


def _mae(values: list[float]) -> float:
    return sum(abs(v) for v in values) / len(values) if values else math.nan


def _run_one(task: tuple[str, str, int, int, int, list[str] | None, Path | None]) -> dict:
    """One setting's suite through both methods: the figures, small enough to send back."""
    from services.cli.bench import accuracy

    name, suite, trials, frames, seed, objects, cache = task
    outcomes = accuracy.run_suite(
        suite, trials, frames, seed, METHODS, objects, SETTINGS[name].sensor(), None, cache
    )
    figures: dict[str, Any] = {}
    for method, done in outcomes.items():
        rows = [
            (o.view.subject, o.view.truth.shape, o.correct, o.width_error_mm, o.angle_error_deg)
            for o in done
        ]
        handled = (
            accuracy.objects_handled(accuracy.irregular_verdicts(done))
            if suite == "irregular"
            else {}
        )
        figures[method] = {
            "rows": rows,
            "failed": [n for n, ok in handled.items() if not ok],
            "objects": len(handled),
        }
    return {"setting": name, "suite": suite, "methods": figures}


def summarise(results: list[dict]) -> dict[str, Any]:
    """Per setting and method: shapes (width MAE, per-frame %), angle MAE, irregular objects
    handled, and per object; the JSON that ``--json`` writes and ``--against`` reads."""
    out: dict[str, Any] = {}
    for r in results:
        for method, fig in r["methods"].items():
            entry = out.setdefault(r["setting"], {}).setdefault(method, {"suites": {}})
            entry["suites"][r["suite"]] = fig
    for methods in out.values():
        for entry in methods.values():
            table: dict[str, list[float]] = {}
            by_shape: dict[str, list[tuple]] = defaultdict(list)
            by_object: dict[str, list[tuple]] = defaultdict(list)
            # The shapes' table is the functional set's, else the first suite with shapes.
            shaped = next((s for s in SHAPE_SUITES if s in entry["suites"]), None)
            for suite, fig in entry["suites"].items():
                for row in fig["rows"]:
                    if suite == shaped:
                        by_shape[row[1]].append(row)
                    by_object[f"{suite}:{row[0]}"].append(row)
            right_all = []
            for shape in SHAPES:
                rows = by_shape.get(shape, [])
                right = [r for r in rows if r[2]]
                right_all += right
                pct = 100.0 * len(right) / len(rows) if rows else math.nan
                table[shape] = [_mae([r[3] for r in right if r[3] is not None]), pct]
            all_rows = [r for rows in by_shape.values() for r in rows]
            table["all"] = [
                _mae([r[3] for r in right_all if r[3] is not None]),
                100.0 * len(right_all) / len(all_rows) if all_rows else math.nan,
            ]
            table["angle"] = [_mae([r[4] for r in right_all if r[4] is not None]), 100.0]
            irregular = entry["suites"].get("irregular")
            if irregular is not None:
                table["irregular"] = [
                    irregular["objects"] - len(irregular["failed"]),
                    irregular["objects"],
                ]
                entry["failed"] = irregular["failed"]
            entry["table"] = table
            entry["objects"] = {
                name: [
                    _mae([r[3] for r in rows if r[2] and r[3] is not None]),
                    100.0 * sum(r[2] for r in rows) / len(rows),
                    _mae([r[4] for r in rows if r[2] and r[4] is not None]),
                ]
                for name, rows in by_object.items()
            }
            del entry["suites"]
    return out


def _cell(value: list[float] | None, column: str = "") -> str:
    if value is None:
        return "-"
    v, pct = value
    if column == "irregular":  # objects handled of objects seen
        return f"{v:.0f}/{pct:.0f}"
    text = "-" if math.isnan(v) else f"{v:.1f}"
    return text if math.isnan(pct) or pct >= 100.0 else f"{pct:.0f}% {text}"


def _pair(
    before: list[float] | None, after: list[float] | None, against: bool, column: str = ""
) -> str:
    a = _cell(after, column)
    if not against:
        return a
    b = _cell(before, column)
    return a if a == b else f"{b} -> {a}"


def report(figures: dict, before: dict | None) -> list[str]:
    lines = []
    columns = ("sphere", "cylinder", "cuboid", "all", "angle", "irregular")
    for method in METHODS:
        lines += [
            "",
            f"method {method}: width MAE mm per shape (functional set, else rotation; shape % "
            "per frame where below 100), wrist angle MAE deg, irregular objects handled",
            "| setting | " + " | ".join(columns) + " |",
            "|---" * (len(columns) + 1) + "|",
        ]
        for name, methods in figures.items():
            table = methods[method]["table"]
            old = (before or {}).get(name, {}).get(method, {}).get("table", {})
            cells = [_pair(old.get(c), table.get(c), before is not None, c) for c in columns]
            lines.append(f"| {SETTINGS[name].label} | " + " | ".join(cells) + " |")
        failed = {n: m[method].get("failed") for n, m in figures.items() if m[method].get("failed")}
        for name, objects in failed.items():
            lines.append(f"  {SETTINGS[name].label}: irregular failed: {', '.join(objects)}")
    return lines


def report_objects(figures: dict, before: dict | None) -> list[str]:
    lines = []
    for method in METHODS:
        names = list(figures)
        lines += [
            "",
            f"method {method} per object: width MAE mm / angle MAE deg",
            "| object | " + " | ".join(SETTINGS[n].label for n in names) + " |",
            "|---" * (len(names) + 1) + "|",
        ]
        objects = list(dict.fromkeys(o for n in names for o in figures[n][method]["objects"]))
        for obj in objects:
            cells = []
            for n in names:
                now = figures[n][method]["objects"].get(obj)
                old = (before or {}).get(n, {}).get(method, {}).get("objects", {}).get(obj)
                width = _pair(
                    old[:2] if old else None, now[:2] if now else None, before is not None
                )
                angle = _pair(
                    [old[2], 100.0] if old else None,
                    [now[2], 100.0] if now else None,
                    before is not None,
                )
                cells.append(f"{width} / {angle}")
            lines.append(f"| {obj} | " + " | ".join(cells) + " |")
    return lines


def run(args: argparse.Namespace) -> int:
    try:
        names = _setting_names(args)
        if args.trials < 1 or args.frames < 1 or args.jobs < 0:
            raise ValueError("--trials and --frames must be >= 1, --jobs >= 0")
        before = json.loads(args.against.read_text()) if args.against else None
        for name in names:
            SETTINGS[name].sensor()  # a bad setting or a missing OpenCV says so before any work
    except (ValueError, OSError, ImportError) as exc:
        print(f"lpc bench sweep: error: {exc}", file=sys.stderr)
        return 2
    suites = list(dict.fromkeys(args.suite or ["functional", "irregular"]))
    tasks = [
        (n, s, args.trials, args.frames, args.seed, args.object, args.cache)
        for n in names
        for s in suites
    ]
    print(
        f"lpc bench sweep: {len(names)} setting(s) x {', '.join(suites)}, {args.trials} trial(s) "
        f"x {args.frames} frames per object, seed {args.seed}, methods {', '.join(METHODS)}"
        + (f"; against {args.against}" if args.against else "")
    )
    results = []
    if args.jobs <= 1:
        done = map(_run_one, tasks)
    else:
        # fork: the workers share the parent's imports and need nothing pickled but the task.
        pool = multiprocessing.get_context("fork").Pool(min(args.jobs, len(tasks)))
        done = pool.imap_unordered(_run_one, tasks)
    for k, result in enumerate(done, start=1):
        results.append(result)
        print(f"sweep: {k}/{len(tasks)} ({result['setting']} {result['suite']})", file=sys.stderr)
    if args.jobs > 1:
        pool.close()
    # The order of the settings as asked, whatever order the workers finished in.
    results.sort(key=lambda r: (names.index(r["setting"]), suites.index(r["suite"])))
    figures = summarise(results)
    print("\n".join(report(figures, before)))
    if args.objects:
        print("\n".join(report_objects(figures, before)))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1))
        print(f"\nwrote {args.json}")
    return 0
