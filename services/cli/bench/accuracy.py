"""``lpc bench accuracy``: the paper's evaluations of the four-line method, on simulated frames.

Runs the suites of ``services/cli/_laser_views.py`` (rotation test, the ten functional objects,
the irregular objects, clutter) through the scan-line cut and ``reconstruct_laser`` and prints,
beside the paper's figures: per-frame and windowed shape accuracy per shape, grasp width and
wrist angle errors (mean absolute, SD), compute time per frame (p50, p99) and points per frame.
Progress goes to stderr. ``--method paper`` runs the paper's own decision rules instead,
``--method cloud`` the full-cloud method (``reconstruct_cloud`` on the whole frame; the paper
column then holds the paper's full-cloud benchmark where it has a figure).

``--sensor stereo`` renders the same views with the simulated stereo camera (two IR images
matched by OpenCV, ``lpc_core.sim.stereo``) instead of the noise model; ``--matcher``,
``--block-size``, ``--uniqueness``, ``--texture-threshold`` and ``--dot-density`` set it.
``--rs-filters spatial,temporal,hole_filling`` runs each frame through librealsense's own
post-processing filters (a pyrealsense2 software device), the temporal one over each trial's
frames in order, to show what each does to the frames.

    lpc bench accuracy                # every suite, 5 trials x 10 frames per object
    lpc bench accuracy --quick        # CI-sized: 1 trial x 10 frames
    lpc bench accuracy --suite functional --trials 20
    lpc bench accuracy --quick --sensor stereo --matcher bm --block-size 9
    lpc bench accuracy --quick --sensor stereo --cache /tmp/lpc-frames   # render once
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from lpc_core.perception.laser import LaserParams, reconstruct_laser
from lpc_core.perception.reconstruction import SHAPES, Reconstruction, wrap_half_turn
from lpc_core.perception.scans import cut_scan_lines
from lpc_core.perception.window import WindowState, window_step
from lpc_core.sim import scene
from lpc_core.sim.stereo import StereoSensor
from services.cli import _laser_views as lv
from services.drivers.depth import (
    SoftwareFilters,
    SourceUnavailable,
)
from services.drivers.depth_flags import (
    add_sensor_arguments,
    rs_filters_arg,
    sensor_label,
    stereo_sensor,
)

# The paper's figures (reference/paper.tex, Results).
PAPER_FRAME_PCT = {"sphere": 96.5, "cylinder": 95.3, "cuboid": 89.0}
PAPER_WINDOW_PCT = {"sphere": 100.0, "cylinder": 97.5, "cuboid": 100.0}
PAPER_WIDTH = "8 ± 5"
PAPER_ANGLE = "2 ± 3"
PAPER_MS = "138"
PAPER_POINTS = "700 ± 300"
PAPER_ROTATION = {
    "prism_40": "36.4 ± 0.3",
    "cylinder_40": "60.3 ± 4.5",
    "cylinder_75": "65.4 ± 3.8",
}
# The paper's full-point-cloud benchmark (Castro et al. 2022), per frame only.
PAPER_CLOUD_FRAME_PCT = {"sphere": 98.0, "cylinder": 93.0, "cuboid": 100.0}
PAPER_CLOUD_WIDTH = "4 ± 3"
PAPER_IRREGULAR_FAILED = ("horse_toy", "banana", "jar_cap")
IRREGULAR_WIDTH_MM, IRREGULAR_ANGLE_DEG, IRREGULAR_SD_DEG = 20.0, 10.0, 15.0
TARGETS = "targets: shape >= 99% per frame and 100% windowed, width MAE <= 3 mm, angle <= 2 deg"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--suite",
        action="append",
        choices=(*lv.SUITES, "all"),
        help="suite to run, repeatable (default: all)",
    )
    parser.add_argument("--trials", type=int, default=None, help="trials per object (default 5)")
    parser.add_argument("--frames", type=int, default=10, help="frames per trial (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of poses and noise")
    parser.add_argument(
        "--method",
        action="append",
        choices=("laser", "paper", "cloud"),
        help="lpc's four-line method (default), the paper's rules, or lpc's full-cloud method; "
        "repeatable: each runs on the same frames",
    )
    parser.add_argument("--quick", action="store_true", help="1 trial per object (CI-sized)")
    parser.add_argument(
        "--failures", action="store_true", help="print every frame whose shape is wrong"
    )
    parser.add_argument(
        "--object", action="append", metavar="NAME", help="only this object, repeatable"
    )
    add_sensor_arguments(parser)
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="keep the stereo frames rendered in DIR and read them back on later runs "
        "(keyed by scene, pose, seed and sensor settings)",
    )
    parser.add_argument(
        "--rs-filters",
        type=rs_filters_arg,
        default=(),
        metavar="LIST",
        help="run the frames through librealsense's filters first (spatial, temporal, "
        "hole_filling; needs pyrealsense2)",
    )


@dataclass(frozen=True)
class Outcome:
    view: lv.View
    result: Reconstruction
    compute_ms: float
    cut_ms: float

    @property
    def correct(self) -> bool:
        return self.result.shape == self.view.truth.shape

    @property
    def width_error_mm(self) -> float | None:
        if self.result.grasp_width_m is None:
            return None
        return 1000.0 * (self.result.grasp_width_m - self.view.truth.grasp_width_m)

    @property
    def angle_error_deg(self) -> float | None:
        error = _angle_error(self.result.wrist_angle_rad, self.view.truth.wrist_angle_rad)
        if error is not None and self.view.square_face:
            # Either edge of a square face is a principal axis: the error is modulo 90 deg.
            error = (error + 45.0) % 90.0 - 45.0
        return error


def _angle_error(got: float | None, want: float | None) -> float | None:
    if got is None or want is None:
        return None
    return math.degrees(wrap_half_turn(got - want))


@dataclass
class Tally:
    frames: int = 0
    correct: int = 0
    width_mm: list[float] = field(default_factory=list)
    angle_deg: list[float] = field(default_factory=list)

    def add(self, correct: bool, width: float | None, angle: float | None) -> None:
        self.frames += 1
        self.correct += correct
        if correct and width is not None:
            self.width_mm.append(width)
        if correct and angle is not None:
            self.angle_deg.append(angle)

    @property
    def pct(self) -> float:
        return 100.0 * self.correct / self.frames if self.frames else math.nan


def _mae_sd(values: list[float]) -> str:
    if not values:
        return "-"
    a = np.abs(np.asarray(values))
    return f"{a.mean():.1f} ± {a.std():.1f}"


def _progress(suite: str, done: int, total: int) -> None:
    step = max(1, total // 10)
    if done % step == 0 or done == total:
        print(f"{suite}: {done}/{total} frames", file=sys.stderr, flush=True)


def _reconstruct(method: str, view: lv.View) -> tuple[Reconstruction, float, float]:
    """(result, CPU ms of the reconstruction, CPU ms of the scan cut) of one method."""
    start = time.process_time()
    if method == "cloud":
        from lpc_core.perception.cloud import reconstruct_cloud

        middle = start
        result = reconstruct_cloud(view.depth, lv.INTRINSICS, seed=view.seq)
    else:
        lines = cut_scan_lines(view.depth, lv.INTRINSICS)
        middle = time.process_time()
        params = LaserParams(variant="lpc" if method == "laser" else "paper")
        result = reconstruct_laser(lines, params, seed=view.seq)
    end = time.process_time()
    return result, 1000 * (end - middle), 1000 * (middle - start)


def run_suite(
    suite: str,
    trials: int,
    frames: int,
    seed: int,
    methods: tuple[str, ...] = ("laser",),
    names: list[str] | None = None,
    sensor: StereoSensor | None = None,
    filters: SoftwareFilters | None = None,
    cache: Path | None = None,
) -> dict[str, list[Outcome]]:
    """Every view of ``suite`` reconstructed by each of ``methods`` (laser, paper, cloud), all
    on the same frames: a stereo frame costs far more to render than to reconstruct."""
    total = lv.count(suite, trials, frames, names)
    outcomes: dict[str, list[Outcome]] = {m: [] for m in methods}
    views = lv.views(suite, trials, frames, seed, names=names, sensor=sensor, cache=cache)
    for k, view in enumerate(views, start=1):
        if filters is not None:
            if view.frame == 0:
                filters.reset()  # the temporal filter's history is one trial's frames
            view = replace(view, depth=filters.process(view.depth))
        for method in methods:
            outcomes[method].append(Outcome(view, *_reconstruct(method, view)))
        _progress(suite, k, total)
    return outcomes


def _trials(outcomes: list[Outcome]) -> dict[tuple[str, str, int], list[Outcome]]:
    grouped: dict[tuple[str, str, int], list[Outcome]] = defaultdict(list)
    for o in outcomes:
        grouped[(o.view.subject, o.view.detail, o.view.trial)].append(o)
    return grouped


def _windowed(trial: list[Outcome]) -> tuple[bool, float | None, float | None, bool]:
    """The window after the trial's last frame: shape right, width and angle errors, flag."""
    state = WindowState()
    window = None
    for o in trial:
        state, window = window_step(state, o.result, o.view.seq, o.view.frame * 11_111_111)
    assert window is not None
    truth = trial[-1].view.truth
    correct = window.shape == truth.shape
    width = (
        None
        if window.grasp_width_m is None
        else 1000 * (window.grasp_width_m - truth.grasp_width_m)
    )
    angle = _angle_error(window.wrist_angle_rad, truth.wrist_angle_rad)
    if angle is not None and trial[-1].view.square_face:
        angle = (angle + 45.0) % 90.0 - 45.0
    return correct, width, angle, window.reconstructed


def report_shapes(
    title: str, outcomes: list[Outcome], show_objects: bool = True, cloud: bool = False
) -> list[str]:
    per_frame = {s: Tally() for s in SHAPES}
    per_window = {s: Tally() for s in SHAPES}
    per_object: dict[str, Tally] = defaultdict(Tally)
    flagged = 0
    for o in outcomes:
        per_frame[o.view.truth.shape].add(o.correct, o.width_error_mm, o.angle_error_deg)
        per_object[o.view.subject].add(o.correct, o.width_error_mm, o.angle_error_deg)
    trials = _trials(outcomes)
    for trial in trials.values():
        correct, width, angle, reconstructed = _windowed(trial)
        per_window[trial[-1].view.truth.shape].add(correct, width, angle)
        flagged += reconstructed
    lines = [title, f"{'':10}{'frames':>7} {'per frame %':>16} {'window %':>16} "
             f"{'width err mm':>22} {'angle err deg':>22}",
             f"{'':10}{'':>7} {'lpc':>7} {'paper':>8} {'lpc':>7} {'paper':>8} "
             f"{'frame':>11} {'window':>10} {'frame':>11} {'window':>10}"]  # fmt: skip
    for shape in SHAPES:
        f, w = per_frame[shape], per_window[shape]
        if not f.frames:
            continue
        paper_frame = (PAPER_CLOUD_FRAME_PCT if cloud else PAPER_FRAME_PCT)[shape]
        paper_window = "-" if cloud else f"{PAPER_WINDOW_PCT[shape]:.1f}"
        lines.append(
            f"{shape:10}{f.frames:7d} {f.pct:7.1f} {paper_frame:8.1f} "
            f"{w.pct:7.1f} {paper_window:>8} {_mae_sd(f.width_mm):>11} "
            f"{_mae_sd(w.width_mm):>10} {_mae_sd(f.angle_deg):>11} {_mae_sd(w.angle_deg):>10}"
        )
    all_f, all_w = Tally(), Tally()
    for t in per_frame.values():
        all_f.frames, all_f.correct = all_f.frames + t.frames, all_f.correct + t.correct
        all_f.width_mm += t.width_mm
        all_f.angle_deg += t.angle_deg
    for t in per_window.values():
        all_w.frames, all_w.correct = all_w.frames + t.frames, all_w.correct + t.correct
        all_w.width_mm += t.width_mm
        all_w.angle_deg += t.angle_deg
    lines.append(
        f"{'all':10}{all_f.frames:7d} {all_f.pct:7.1f} {'':8} {all_w.pct:7.1f} {'':8} "
        f"{_mae_sd(all_f.width_mm):>11} {_mae_sd(all_w.width_mm):>10} "
        f"{_mae_sd(all_f.angle_deg):>11} {_mae_sd(all_w.angle_deg):>10}"
    )
    lines.append(
        f"{'paper':10}{'':7} {'':7} {'':8} {'':7} {'':8} "
        f"{PAPER_CLOUD_WIDTH if cloud else PAPER_WIDTH:>11} {'':>10} "
        f"{PAPER_ANGLE:>11}"
    )
    lines.append(f"  windows flagged reconstructed: {flagged}/{len(trials)}")
    if show_objects:
        lines.append(f"  {'object':24} {'shape %':>8} {'width MAE':>10} {'angle MAE':>10}")
        for name, t in per_object.items():
            width = f"{np.abs(t.width_mm).mean():.1f}" if t.width_mm else "-"
            angle = f"{np.abs(t.angle_deg).mean():.1f}" if t.angle_deg else "-"
            lines.append(f"  {name:24} {t.pct:8.1f} {width:>10} {angle:>10}")
    return lines


def report_rotation(outcomes: list[Outcome]) -> list[str]:
    lines = [
        "rotation test: objects lying on the table, seen from above, six wrist angles 30 deg apart",
        f"  {'object':12} {'truth':>6} {'estimate mm':>14} {'paper mm':>12} {'shape %':>8} "
        f"{'angle err deg':>14}",
    ]
    by_object: dict[str, list[Outcome]] = defaultdict(list)
    for o in outcomes:
        by_object[o.view.subject].append(o)
    for name, group in by_object.items():
        widths = [o.result.grasp_width_mm for o in group if o.correct and o.result.grasp_width_mm]
        est = f"{np.mean(widths):.1f} ± {np.std(widths):.1f}" if widths else "-"
        angles = [o.angle_error_deg for o in group if o.correct and o.angle_error_deg is not None]
        pct = 100.0 * sum(o.correct for o in group) / len(group)
        lines.append(
            f"  {name:12} {group[0].view.truth.grasp_width_mm:6.1f} {est:>14} "
            f"{PAPER_ROTATION.get(name, '-'):>12} {pct:8.1f} {_mae_sd(angles):>14}"
        )
    lines.append("  per wrist angle (estimate mm, all three objects):")
    by_angle: dict[str, list[str]] = defaultdict(list)
    for name, group in by_object.items():
        for detail in dict.fromkeys(o.view.detail for o in group):
            w = [o.result.grasp_width_mm for o in group if o.view.detail == detail and o.correct]
            by_angle[detail].append(f"{name} {np.mean(w):.1f}" if w else f"{name} -")
    for detail, cells in by_angle.items():
        lines.append(f"    {detail}: " + ", ".join(cells))
    return lines


@dataclass(frozen=True)
class IrregularVerdict:
    """One irregular object seen from one side, judged by the paper's rule on its frames."""

    name: str
    detail: str
    truth: scene.ObjectTruth
    shape_pct: float
    width_mm: float  # the median of the frames' estimates
    angle_error_deg: float  # the median of the frames' errors
    angle_sd_deg: float  # the spread of the errors about that median
    handled: bool


def irregular_verdicts(outcomes: list[Outcome]) -> list[IrregularVerdict]:
    """The paper's rule per object and view: width within ±20 mm and angle within ±10 deg
    (the frames' medians), the angle errors' SD below 15 deg, half the frames reconstructed."""
    groups: dict[tuple[str, str], list[Outcome]] = defaultdict(list)
    for o in outcomes:
        groups[(o.view.subject, o.view.detail)].append(o)
    verdicts = []
    for (name, detail), group in groups.items():
        truth = group[0].view.truth
        done = [o for o in group if o.result.shape != "none"]
        widths = [o.result.grasp_width_mm for o in done if o.result.grasp_width_mm is not None]
        est = float(np.median(widths)) if widths else math.nan
        errors = [e for o in done if (e := o.angle_error_deg) is not None]
        angle_err = float(np.median(errors)) if errors else math.nan
        # The spread of the estimates around the truth (trials differ in wrist roll).
        sd = (
            float(np.sqrt(np.mean(np.square(np.array(errors) - angle_err)))) if errors else math.nan
        )
        ok = len(done) >= len(group) / 2 and abs(est - truth.grasp_width_mm) <= IRREGULAR_WIDTH_MM
        if truth.wrist_angle_rad is not None:
            ok = ok and abs(angle_err) <= IRREGULAR_ANGLE_DEG and sd < IRREGULAR_SD_DEG
        pct = 100.0 * sum(o.correct for o in group) / len(group)
        verdicts.append(IrregularVerdict(name, detail, truth, pct, est, angle_err, sd, bool(ok)))
    return verdicts


def objects_handled(verdicts: list[IrregularVerdict]) -> dict[str, bool]:
    """An object is handled when every view of it is."""
    handled: dict[str, bool] = {}
    for v in verdicts:
        handled[v.name] = handled.get(v.name, True) and v.handled
    return handled


def report_irregular(outcomes: list[Outcome]) -> list[str]:
    lines = [
        "irregular objects (paper's rule: width within ±20 mm, angle within ±10 deg, angle SD "
        "< 15 deg; here the per-frame medians, the SD of the angle errors, and at least half "
        "the frames reconstructed)",
        f"  {'object':18} {'view':6} {'shape':9} {'shape %':>8} {'truth mm':>9} {'est mm':>7} "
        f"{'angle err':>9} {'angle SD':>8} {'result':>7} {'paper':>6}",
    ]
    verdicts = irregular_verdicts(outcomes)
    for v in verdicts:
        paper = "fail" if v.name in PAPER_IRREGULAR_FAILED else "ok"
        lines.append(
            f"  {v.name:18} {v.detail:6} {v.truth.shape:9} {v.shape_pct:8.1f} "
            f"{v.truth.grasp_width_mm:9.1f} {v.width_mm:7.1f} {v.angle_error_deg:9.1f} "
            f"{v.angle_sd_deg:8.1f} {'ok' if v.handled else 'FAIL':>7} {paper:>6}"
        )
    passed = objects_handled(verdicts)
    lines.append(
        f"  objects handled: {sum(passed.values())}/{len(passed)} "
        f"(paper: {len(passed) - len(PAPER_IRREGULAR_FAILED)}/{len(passed)}; it failed "
        f"{', '.join(PAPER_IRREGULAR_FAILED)})"
    )
    return lines


def report_cost(outcomes: list[Outcome]) -> list[str]:
    ms = np.array([o.compute_ms for o in outcomes])
    cut = np.array([o.cut_ms for o in outcomes])
    pts = np.array([o.result.points for o in outcomes])
    return [
        f"  CPU per frame of the reconstruction: p50 {np.percentile(ms, 50):.2f} ms, "
        f"p99 {np.percentile(ms, 99):.2f} ms (paper {PAPER_MS} ms, C++); scan cut p50 "
        f"{np.percentile(cut, 50):.2f} ms",
        f"  points per frame: {pts.mean():.0f} ± {pts.std():.0f} (paper {PAPER_POINTS})",
    ]


def _failures(outcomes: list[Outcome]) -> list[str]:
    lines = []
    for o in outcomes:
        if not o.correct:
            v, r = o.view, o.result
            lines.append(
                f"  wrong: {v.suite} {v.subject} {v.detail} trial {v.trial} frame {v.frame}: "
                f"{r.shape} (truth {v.truth.shape}) {r.reason}"
            )
    return lines


def _suite_report(suite: str, method: str, outcomes: list[Outcome], failures: bool) -> list[str]:
    if suite == "rotation":
        lines = report_rotation(outcomes)
    elif suite == "irregular":
        lines = report_irregular(outcomes)
    else:
        title = {
            "functional": "functional set: the paper's ten objects (upright, lying, tilted)",
            "clutter": "clutter: the table inside the capture volume, or a neighbouring object",
        }[suite]
        lines = report_shapes(
            title, outcomes, show_objects=suite == "functional", cloud=method == "cloud"
        )
    lines += report_cost(outcomes)
    if failures:
        lines += _failures(outcomes)
    return lines


def run(args: argparse.Namespace) -> int:
    suites = args.suite or ["all"]
    if "all" in suites:
        suites = list(lv.SUITES)
    trials = args.trials if args.trials is not None else (1 if args.quick else 5)
    if trials < 1 or args.frames < 1:
        print("lpc bench accuracy: error: --trials and --frames must be >= 1", file=sys.stderr)
        return 2
    try:
        sensor = stereo_sensor(args)
    except ValueError as exc:
        print(f"lpc bench accuracy: error: {exc}", file=sys.stderr)
        return 2
    filters = None
    if args.rs_filters:
        try:
            filters = SoftwareFilters(lv.INTRINSICS, args.rs_filters)
        except SourceUnavailable as exc:
            print(f"lpc bench accuracy: error: {exc}", file=sys.stderr)
            return 2
    methods = tuple(dict.fromkeys(args.method or ["laser"]))
    print(
        f"lpc bench accuracy: method {', '.join(methods)}, {trials} trial(s) x {args.frames} "
        f"frames per object, seed {args.seed}, sensor: {sensor_label(args)}, librealsense "
        f"filters: {','.join(args.rs_filters) or 'none'}; {TARGETS}"
    )
    everything: dict[str, list[Outcome]] = {m: [] for m in methods}
    for suite in dict.fromkeys(suites):
        by_method = run_suite(
            suite, trials, args.frames, args.seed, methods, args.object, sensor, filters, args.cache
        )
        for method, outcomes in by_method.items():
            if not outcomes:
                continue
            everything[method] += outcomes
            print()
            if len(methods) > 1:
                print(f"[method {method}]")
            print("\n".join(_suite_report(suite, method, outcomes, args.failures)), flush=True)
    if len(suites) > 1:
        for method, outcomes in everything.items():
            print()
            print("\n".join([f"all suites, method {method}:", *report_cost(outcomes)]))
    if filters is not None:
        filters.close()
    return 0
