"""Simulated grasping trials: the paper's pick-and-place experiment, run in process.

The protocol (reference/paper.tex, "Experimental Protocol"): each person grasps the ten
functional objects in a fixed order, five times over (blocks), and carries each one to a drop
zone 0.5 m away. The time to accomplish the task (TAT) runs from the start of the reach until
the object is released. A trial whose grasp fails (the hand hits the object, or the object
slips) is repeated, and counted as a failure.

Each 10 ms tick of simulated time, in this order (the order ``lpc replay`` reproduces):

0. the controller's 100 Hz timer tick;
1. reconstructions due now leave the reconstructor and pass the 10-frame window; the grasp
   target goes to the aim step and the controller;
2. the virtual user (``lpc_core.sim.virtual_user``) perceives the tactors, the hand and the
   object, and moves the arm (the camera) and its muscles (an EMG sample);
3. the controller takes the EMG sample, the simulated hand (``lpc_core.sim.hand``) moves under the
   last command and reports its state, and the controller answers it with a command;
4. on a camera tick, the scene is rendered from the camera pose (``lpc_core.sim.scene``), cut into
   scan lines (``pipeline.scans_step``), turned into an aim cue and a tactor command
   (``aim.aim_step``) for the controller and the user, and offered to the reconstructor.

Every step is the services' own step function; only the clock is simulated, and nothing here
reads one. Outputs go to an optional ``sink(key, message, log_time_ns)`` with the bus topic of
each message, so that a trial can be recorded as a live session would be.

Simulated rates, and why
    The camera runs at ``camera_hz`` (default 20 Hz, not the D435's 90 Hz): the aim cue the
    person follows is then at most 50 ms old, well under a tactile reaction time (>= 150 ms),
    and rendering costs a fifth. The reconstructor behaves as the live service does (one
    worker, the newest waiting frame kept, ``reconstructor``'s bookkeeping), but a
    reconstruction takes the paper's measured mean time, ``recon_period_s`` (138 ms for the
    four-line method, 75 ms for the full-cloud benchmark), rather than this machine's: the
    prototype's 10-frame window fills in about 1.4 s, the benchmark's in 0.75 s, as in the
    paper. After the take-over the controller ignores vision (direct control), so no frames
    are rendered until the trial ends. Only the pixels the method reads are rendered: the
    capture volume's window for the four lines, the crop box's for the cloud.

Geometry
    The object rests on a table at the world origin; the arm moves in the *aim frame*, the
    camera pose whose optical axis pierces the object's centre from ``standoff_m``, seen from
    the direction the sequence gives. The camera is on the hand, so it turns with the
    prosthesis' wrist: camera pose = aim pose x offset x roll(wrist angle). The controller
    aligns the object's axis with image angle 0 (``ControllerParams.wrist_offset_deg`` = 0), so
    a correct pre-shape leaves the object's axis at 0 degrees in the image.

Grasp physics
    When the open hand reaches around the object (the user's ``envelop``), an aperture smaller
    than the object's width hits it (failure "collision"); otherwise the object is between the
    fingers. An orientation error beyond ``slip_deg`` for a cylinder or a cuboid lets the object
    slip when lifted (failure "slipped").
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Literal

import numpy as np

from lpc_core.control.aim import AimParams, AimState, aim_step
from lpc_core.control.controller import ControllerCore, ControllerParams, controller_step
from lpc_core.control.controller import Tick as ControllerTick
from lpc_core.control.emg import EmgProfile, calibrate
from lpc_core.devices.hand import HandCommand
from lpc_core.perception.cloud import CloudParams, reconstruct_cloud
from lpc_core.perception.intrinsics import D435_424X240, Intrinsics
from lpc_core.perception.laser import LaserParams
from lpc_core.perception.pipeline import ScansState, intrinsics_to_message, scans_step
from lpc_core.perception.reconstructor import (
    PoolParams,
    PoolState,
    Release,
    Submit,
    frame_arrived,
    frame_done,
    reconstruct_message,
    reconstruction_message,
    window_message,
)
from lpc_core.perception.scans import ScanParams
from lpc_core.perception.window import WindowParams, WindowState
from lpc_core.replay import KEY_OF_TYPE
from lpc_core.sim import scene as sc
from lpc_core.sim.emg_sim import PERIOD_NS, MuscleParams, MuscleState, simulate_emg
from lpc_core.sim.hand import HandParams, HandState, hand_step
from lpc_core.sim.timeline import DEFAULT_ORDER
from lpc_core.sim.virtual_user import (
    Percept,
    UserParams,
    UserState,
    axial_error_deg,
    individual,
    individual_muscles,
    new_trial,
    user_step,
)
from schemas import (
    AimCue,
    ControllerState,
    DepthFrame,
    EmgSample,
    GraspTarget,
    ObjectTruth,
    ProsthesisCommand,
    ProsthesisState,
    Reconstruction,
    ScanLines,
    TactorCommand,
    to_wire,
)

Method = Literal["laser", "cloud"]
Sink = Callable[[str, Any, int], None]

PAPER_PERIOD_S: dict[str, float] = {"laser": 0.138, "cloud": 0.075}
"""Mean time per reconstruction the paper measured (Results): 138 ms and 75 ms."""

PAPER_SEQUENCE: tuple[tuple[str, float, float], ...] = DEFAULT_ORDER
"""(object, azimuth_deg, elevation_deg): the ten functional objects in a fixed order that
alternates shapes and orientations, as the paper's sequence does (its Fig. 5B is not in the
text; this is ``lpc_core.sim.timeline``'s rendition)."""

PAPER_TAT_S: dict[str, tuple[tuple[float, float], ...]] = {
    # Block 1 and block 5 as reported: median {IQR}, seconds (Results).
    "laser": ((16.7, 6.0), (12.5, 4.0)),
    "cloud": ((10.4, 2.9), (8.8, 0.7)),
}

BASE_NS = 1_000_000_000
EMG_SOURCE = "virtual-user"
"""``EmgSample.source`` of the trials: not ``"sim"``, which replay takes for ``lpc up``'s
scripted user (its calibration, a fixed camera)."""
_VISION_MODES = frozenset({"idle", "aiming", "ready", "preshaping"})


@dataclass(frozen=True, kw_only=True)
class TrialConfig:
    """One experimental condition and the simulation's settings (SI units)."""

    method: Method = "laser"
    feedback: bool = True
    camera_hz: float = 20.0
    recon_period_s: float | None = None  # None: the paper's figure for the method
    recon_workers: int = 1
    window: WindowParams = field(default_factory=WindowParams)
    lead_in_s: float = 0.5  # rest before the reach: the controller leaves "stopped"
    max_trial_s: float = 60.0
    max_attempts: int = 3
    slip_deg: float = 25.0
    user: UserParams = field(default_factory=UserParams)
    muscles: MuscleParams = field(default_factory=MuscleParams)
    hand: HandParams = field(default_factory=HandParams)
    intrinsics: Intrinsics = D435_424X240
    noise: sc.NoiseModel = field(default_factory=sc.NoiseModel)
    scans: ScanParams = field(default_factory=ScanParams)
    laser: LaserParams = field(default_factory=LaserParams)
    cloud: CloudParams = field(default_factory=CloudParams)
    aim: AimParams = field(default_factory=AimParams)
    record_depth: bool = False

    def __post_init__(self) -> None:
        if self.method not in ("laser", "cloud"):
            raise ValueError(f"method must be 'laser' or 'cloud', got {self.method!r}")
        every = 1e9 / PERIOD_NS / self.camera_hz
        if not (self.camera_hz > 0 and abs(every - round(every)) < 1e-9):
            raise ValueError(
                f"camera_hz must divide 100 Hz (e.g. 10, 20, 25, 50), got {self.camera_hz}"
            )
        if self.recon_period_s is not None and not self.recon_period_s > 0:
            raise ValueError(f"recon_period_s must be positive, got {self.recon_period_s}")
        for name in ("max_trial_s", "slip_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.max_attempts < 1 or self.recon_workers < 1:
            raise ValueError("max_attempts and recon_workers must be at least 1")
        if self.lead_in_s < 0.2:
            raise ValueError(f"lead_in_s must be at least 0.2 s, got {self.lead_in_s}")

    @property
    def period_s(self) -> float:
        return (
            self.recon_period_s if self.recon_period_s is not None else PAPER_PERIOD_S[self.method]
        )

    @property
    def frame_every(self) -> int:
        return round(1e9 / PERIOD_NS / self.camera_hz)

    @property
    def condition(self) -> str:
        return f"{self.method}-feedback-{'on' if self.feedback else 'off'}"


# --------------------------------------------------------------------------- people


@dataclass(frozen=True)
class Person:
    """One virtual participant: their skills, their muscles and their EMG calibration."""

    index: int
    params: UserParams
    muscles: MuscleParams
    profile: EmgProfile


def make_person(config: TrialConfig, index: int, seed: int) -> Person:
    """Participant ``index`` of the population seeded by ``seed``: the same person in every
    condition (the paper's participants tried both systems), calibrated as ``lpc emg
    calibrate`` would (rest, then a maximal contraction per channel, through ``calibrate``)."""
    rng = np.random.default_rng((seed, index, 0x5EED))
    params = individual(config.user, rng)
    muscles = individual_muscles(config.muscles, rng, config.user.individual_cv)
    emg_seed = int(rng.integers(2**31))
    _, rest = simulate_emg(MuscleState(), np.zeros((300, 2)), muscles, emg_seed, 0)
    recordings = []
    for channel in range(2):
        drive = np.zeros((300, 2))
        drive[50:250, channel] = 1.0
        _, rec = simulate_emg(MuscleState(), drive, muscles, emg_seed, 1000 * (channel + 1))
        recordings.append(rec)
    profile = calibrate(rest, recordings)
    return Person(index=index, params=params, muscles=muscles, profile=profile)


# --------------------------------------------------------------------------- outcomes


@dataclass(frozen=True, kw_only=True)
class TrialSpec:
    """Which trial: ``practice`` is the person's n-th trial with this controller (1-based)."""

    user: int
    block: int
    index: int
    object_name: str
    azimuth_deg: float
    elevation_deg: float
    practice: int
    seed: int


@dataclass(frozen=True, kw_only=True)
class TrialOutcome:
    """What one trial gave. ``tat_s`` is the successful attempt's TAT (None if every attempt
    failed); ``failures`` the reason of each failed attempt. ``triggers`` counts the quick
    flexions made, ``retriggers`` those beyond the first of each attempt; ``reaims`` the times
    the user stepped back from a wrong pre-shape. ``reconstructed`` says whether the grasp
    target at the take-over had the object's shape; ``frame_success`` is the fraction of
    reconstructions of frames whose optical axis pierced the object that got its shape."""

    user: int
    block: int
    index: int
    object: str
    shape: str
    completed: bool
    tat_s: float | None
    attempts: int
    failures: tuple[str, ...] = ()
    triggers: int = 0
    retriggers: int = 0
    reaims: int = 0
    take_overs: int = 0
    corrections: int = 0
    preshapes: int = 0
    reconstructed: bool = False
    target_shape: str | None = None
    target_width_mm: float | None = None
    true_width_mm: float | None = None
    orientation_error_deg: float | None = None
    frames: int = 0
    reconstructions: int = 0
    pierced_reconstructions: int = 0
    pierced_correct: int = 0
    first_ready_s: float | None = None
    trigger_s: float | None = None
    take_over_s: float | None = None
    sim_s: float = 0.0
    grip: str | None = None  # the grip of the last pre-shape (a one-grip hand does power)

    @property
    def frame_success(self) -> float | None:
        if self.pierced_reconstructions == 0:
            return None
        return self.pierced_correct / self.pierced_reconstructions


@dataclass(frozen=True)
class Carry:
    """What carries from one trial to the next in a block: the hand and the muscles."""

    hand: HandState
    muscle: MuscleState = field(default_factory=MuscleState)


def fresh_carry(config: TrialConfig) -> Carry:
    return Carry(hand=HandState(params=config.hand))


# --------------------------------------------------------------------------- rendering


def render_window(
    intrinsics: Intrinsics,
    x_limits: tuple[float, float],
    y_limits: tuple[float, float],
    z_near: float,
) -> tuple[int, int, int, int]:
    """Pixel rectangle (v0, v1, u0, u1) of the rays that can reach a box of these x, y limits
    at depths from ``z_near`` on (the box's extreme slopes are at its nearest depth)."""
    fx, fy = intrinsics.fx, intrinsics.fy
    u0 = max(math.floor(intrinsics.ppx + fx * min(x_limits[0] / z_near, 0.0)) - 1, 0)
    u1 = min(math.ceil(intrinsics.ppx + fx * max(x_limits[1] / z_near, 0.0)) + 2, intrinsics.width)
    v0 = max(math.floor(intrinsics.ppy + fy * min(y_limits[0] / z_near, 0.0)) - 1, 0)
    v1 = min(math.ceil(intrinsics.ppy + fy * max(y_limits[1] / z_near, 0.0)) + 2, intrinsics.height)
    return v0, v1, u0, u1


@dataclass(frozen=True)
class _Camera:
    intrinsics: Intrinsics
    window: tuple[int, int, int, int]
    cropped: Intrinsics

    @classmethod
    def for_config(cls, config: TrialConfig) -> _Camera:
        intr = config.intrinsics
        if config.method == "laser":
            p = config.scans
            window = render_window(intr, p.x_limits_m, p.y_limits_m, p.z_limits_m[0])
        else:
            c = config.cloud
            lim = (-c.crop_xy_m, c.crop_xy_m)
            window = render_window(intr, lim, lim, c.crop_z_min_m)
        v0, v1, u0, u1 = window
        cropped = dataclasses.replace(
            intr, width=u1 - u0, height=v1 - v0, ppx=intr.ppx - u0, ppy=intr.ppy - v0
        )
        return cls(intr, window, cropped)

    def render(
        self, scene: sc.Scene, pose: np.ndarray, rng: np.random.Generator, noise: sc.NoiseModel
    ) -> np.ndarray:
        v0, v1, u0, u1 = self.window
        depth = np.zeros((self.intrinsics.height, self.intrinsics.width), dtype=np.uint16)
        depth[v0:v1, u0:u1] = sc.render_depth(scene, self.cropped, pose, rng, noise)
        return depth


def _truth_message(truth: sc.ObjectTruth) -> ObjectTruth:
    return ObjectTruth(
        name=truth.name,
        shape=truth.shape,
        grasp_width_mm=truth.grasp_width_mm,
        wrist_angle_deg=truth.wrist_angle_deg,
        pierced=truth.pierced,
    )


# --------------------------------------------------------------------------- one attempt


@dataclass
class _Attempt:
    """Bookkeeping of one attempt (mutable: it lives inside one call)."""

    ok: bool = False
    failure: str = ""
    tat_s: float | None = None
    end_ns: int = 0
    preshapes: int = 0
    frames: int = 0
    reconstructions: int = 0
    pierced: int = 0
    pierced_correct: int = 0
    first_ready_s: float | None = None
    take_over_view: sc.ObjectTruth | None = None
    target: GraspTarget | None = None
    slip: bool = False
    orientation_error_deg: float | None = None
    grip: str | None = None


@dataclass
class _Counters:
    frame_seq: int = 0
    emg_seq: int = 0
    hand_seq: int = 0


def _emit(sink: Sink | None, message: Any, t_ns: int) -> None:
    if sink is not None:
        sink(KEY_OF_TYPE[type(message)], message, t_ns)


def _run_attempt(
    config: TrialConfig,
    camera: _Camera,
    person: Person,
    spec: TrialSpec,
    attempt: int,
    carry: Carry,
    t0_ns: int,
    counters: _Counters,
    sink: Sink | None,
) -> tuple[_Attempt, UserState, Carry]:
    result = _Attempt()
    catalogue = _catalogue()
    obj = catalogue[spec.object_name]
    world = sc.Scene((obj,), sc.table())
    aim = sc.aim_pose(
        obj,
        person.params.standoff_m,
        azimuth_rad=math.radians(spec.azimuth_deg),
        elevation_rad=math.radians(spec.elevation_deg),
    )
    seed = (spec.seed, person.index, spec.block, spec.index, attempt)
    start_ns = t0_ns + round(config.lead_in_s * 1e9)
    user = new_trial(
        person.params,
        person.muscles,
        trial=spec.practice,
        feedback=config.feedback,
        tactor_angles_rad=config.aim.tactor_angles_rad,
        seed=seed,
        start_ns=start_ns,
        lead_in_s=config.lead_in_s,
        max_s=config.max_trial_s,
        muscle=carry.muscle,
    )
    core = ControllerCore(params=ControllerParams(profile=person.profile))
    hand = dataclasses.replace(carry.hand, t_ns=None, object_mm=None, grip_force_pct=0.0)
    scans_state = ScansState(params=config.scans)
    aim_state = AimState(params=config.aim)
    window = WindowState(params=config.window)
    pool = PoolState(params=PoolParams(workers=config.recon_workers, max_pending=1))
    running: dict[int, tuple[int, Reconstruction]] = {}  # seq -> (due time, result)
    intrinsics_msg = intrinsics_to_message(config.intrinsics)
    period_ns = round(config.period_s * 1e9)

    command: HandCommand | None = None
    hand_msg: ProsthesisState | None = None
    tactors: TactorCommand | None = None
    pose = aim
    view = obj.truth(aim @ sc.make_pose(None, person.params.start_offset_m))
    end_ns = start_ns + round(config.max_trial_s * 1e9)
    fail_at_ns: int | None = None
    k = 0

    def to_controller(message: Any, t_ns: int) -> None:
        nonlocal core, command
        core, outputs = controller_step(core, message, t_ns)
        for out in outputs:
            _emit(sink, out, t_ns)
            if isinstance(out, ProsthesisCommand):
                command = HandCommand(grasp=out.grasp, wrist=out.wrist)
            elif isinstance(out, ControllerState) and out.state != out.previous:
                if out.state == "preshaping":
                    result.preshapes += 1
                    result.grip = out.grip
                if out.state == "ready" and result.first_ready_s is None:
                    result.first_ready_s = (t_ns - start_ns) / 1e9
                if out.event == "released":
                    result.ok = True
                    result.tat_s = (t_ns - start_ns) / 1e9

    def to_aim(message: Any, t_ns: int) -> None:
        nonlocal aim_state, tactors
        aim_state, outputs = aim_step(aim_state, message, t_ns)
        for out in outputs:
            _emit(sink, out, t_ns)
            if isinstance(out, TactorCommand):
                tactors = out
            elif isinstance(out, AimCue):
                to_controller(out, t_ns)

    def handle_pool(outputs: list[Any], t_ns: int) -> None:
        nonlocal window
        for out in outputs:
            if isinstance(out, Submit):
                scans_msg, depth, truth = out.job
                message = _reconstruct(config, scans_msg, depth, period_ns / 1e6)
                running[out.seq] = (t_ns + period_ns, message)
                result.reconstructions += 1
                if truth is not None and truth.pierced:
                    result.pierced += 1
                    result.pierced_correct += int(message.shape == truth.shape)
            elif isinstance(out, Release):
                message = out.result
                _emit(sink, message, t_ns)
                window, target = window_message(window, message)
                _emit(sink, target, t_ns)
                to_aim(target, t_ns)
                to_controller(target, t_ns)

    while True:
        t_ns = t0_ns + k * PERIOD_NS
        k += 1
        t_s = (t_ns - start_ns) / 1e9
        if k > 1:
            # The controller's 100 Hz timer, before anything else at this instant; it starts
            # one period after the first input (as the live service's and replay's do).
            to_controller(ControllerTick(t_ns), t_ns)
        # 1. Reconstructions finishing now.
        for seq in sorted(s for s, (due, _) in running.items() if due <= t_ns):
            _, message = running.pop(seq)
            pool, outputs = frame_done(pool, seq, message)
            handle_pool(outputs, t_ns)
        # 2. The person.
        percept = Percept(
            tactors=tactors if config.feedback else None,
            hand=hand_msg,
            width_mm=view.grasp_width_mm,
            axis_deg=None if obj.shape == "sphere" else view.wrist_angle_deg,
        )
        user, action = user_step(user, percept, t_ns)
        frame_due = (
            t_s >= 0 and (k - 1) % config.frame_every == 0 and core.mode.value in _VISION_MODES
        )
        if action.events or frame_due:
            pose = aim @ _hand_pose(action.offset, hand.wrist_deg)
        for event in action.events:
            if event == "take_over":
                result.take_over_view = obj.truth(pose)
                result.target = core.target if core.target_present else None
            elif event == "envelop":
                failure, hand = _envelop(config, obj, result, hand)
                if failure:
                    result.failure = failure
                    fail_at_ns = t_ns
            elif event == "transport" and result.slip:
                result.failure = "slipped"
                fail_at_ns = t_ns + 300_000_000
        # 3. Muscles, controller and hand.
        emg = EmgSample(
            seq=counters.emg_seq, t_ns=t_ns, channels=list(action.emg), source=EMG_SOURCE
        )
        counters.emg_seq += 1
        _emit(sink, emg, t_ns)
        to_controller(emg, t_ns)
        hand, status = hand_step(hand, command, t_ns)
        hand_msg = ProsthesisState(
            seq=counters.hand_seq,
            t_ns=t_ns,
            wrist_angle_deg=status.wrist_angle_deg,
            aperture_mm=status.aperture_mm,
            grip_force_pct=status.grip_force_pct,
        )
        counters.hand_seq += 1
        _emit(sink, hand_msg, t_ns)
        to_controller(hand_msg, t_ns)
        # 4. The camera.
        if frame_due:
            seq = counters.frame_seq
            counters.frame_seq += 1
            rng = np.random.default_rng((*seed, 7, seq))
            depth = camera.render(world, pose, rng, config.noise)
            truth = obj.truth(pose)
            view = truth
            truth_msg = _truth_message(truth)
            frame = DepthFrame(
                seq=seq,
                t_ns=t_ns,
                intrinsics=intrinsics_msg,
                depth=to_wire(depth),
                truth=truth_msg,
            )
            if config.record_depth:
                _emit(sink, frame, t_ns)
            scans_state, scans_msg = scans_step(scans_state, frame, t_ns)
            _emit(sink, scans_msg, t_ns)
            to_aim(scans_msg, t_ns)
            result.frames += 1
            pool, outputs = frame_arrived(pool, scans_msg.seq, (scans_msg, depth, truth))
            handle_pool(outputs, t_ns)
        if result.ok or (fail_at_ns is not None and t_ns >= fail_at_ns):
            break
        if t_ns >= end_ns:
            result.failure = "timeout"
            break
    result.end_ns = t_ns
    if result.take_over_view is not None and obj.shape != "sphere":
        angle = result.take_over_view.wrist_angle_deg
        result.orientation_error_deg = None if angle is None else axial_error_deg(angle)
    return result, user, Carry(hand=dataclasses.replace(hand, object_mm=None), muscle=user.muscle)


def _hand_pose(offset: tuple[float, float, float], wrist_deg: float) -> np.ndarray:
    """The camera in the aim frame: moved by the arm, turned with the wrist about its axis."""
    c, s = math.cos(math.radians(wrist_deg)), math.sin(math.radians(wrist_deg))
    return np.array(
        [
            [c, -s, 0.0, offset[0]],
            [s, c, 0.0, offset[1]],
            [0.0, 0.0, 1.0, offset[2]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _envelop(
    config: TrialConfig, obj: sc.SceneObject, result: _Attempt, hand: HandState
) -> tuple[str, HandState]:
    """The open hand reaches around the object: does it fit, and will it hold?"""
    view = result.take_over_view
    if view is None:
        return "", hand
    width = view.grasp_width_mm
    if hand.aperture_mm < width:
        return f"collision: aperture {hand.aperture_mm:.0f} mm < width {width:.0f} mm", hand
    if obj.shape != "sphere" and view.wrist_angle_deg is not None:
        result.slip = axial_error_deg(view.wrist_angle_deg) > config.slip_deg
    return "", dataclasses.replace(hand, object_mm=width)


def _reconstruct(
    config: TrialConfig, scans: ScanLines, depth: np.ndarray, compute_ms: float
) -> Reconstruction:
    if config.method == "laser":
        return reconstruct_message(scans, config.laser, compute_ms)
    result = reconstruct_cloud(depth, config.intrinsics, config.cloud, seed=scans.frame_seq)
    return reconstruction_message(result, scans, compute_ms)


@lru_cache(maxsize=1)
def _catalogue() -> dict[str, sc.SceneObject]:
    return sc.functional_objects()


# --------------------------------------------------------------------------- trials, blocks


def run_trial(
    config: TrialConfig,
    person: Person,
    spec: TrialSpec,
    carry: Carry,
    sink: Sink | None = None,
) -> tuple[TrialOutcome, Carry]:
    """One trial, repeated after a failed grasp up to ``max_attempts`` times."""
    camera = _Camera.for_config(config)
    counters = _Counters()
    failures: list[str] = []
    triggers = retriggers = reaims = take_overs = corrections = preshapes = 0
    frames = recons = pierced = correct = 0
    t0_ns = BASE_NS
    attempt_result = user = None
    for attempt in range(config.max_attempts):
        attempt_result, user, carry = _run_attempt(
            config, camera, person, spec, attempt, carry, t0_ns, counters, sink
        )
        triggers += user.triggers
        retriggers += max(user.triggers - 1, 0)
        reaims += user.reaims
        take_overs += user.take_overs
        corrections += user.corrections
        preshapes += attempt_result.preshapes
        frames += attempt_result.frames
        recons += attempt_result.reconstructions
        pierced += attempt_result.pierced
        correct += attempt_result.pierced_correct
        if attempt_result.ok:
            break
        failures.append(attempt_result.failure)
        t0_ns = attempt_result.end_ns + 1_000_000_000
    assert attempt_result is not None and user is not None
    a = attempt_result
    moments = {what: t for t, what in reversed(user.log)}
    obj = _catalogue()[spec.object_name]
    target = a.target
    view = a.take_over_view
    outcome = TrialOutcome(
        user=spec.user,
        block=spec.block,
        index=spec.index,
        object=spec.object_name,
        shape=obj.shape,
        completed=a.ok,
        tat_s=a.tat_s,
        attempts=len(failures) + (1 if a.ok else 0),
        failures=tuple(failures),
        triggers=triggers,
        retriggers=retriggers,
        reaims=reaims,
        take_overs=take_overs,
        corrections=corrections,
        preshapes=preshapes,
        reconstructed=target is not None and target.shape == obj.shape,
        target_shape=None if target is None else target.shape,
        target_width_mm=None if target is None else target.grasp_width_mm,
        true_width_mm=None if view is None else view.grasp_width_mm,
        orientation_error_deg=a.orientation_error_deg,
        frames=frames,
        reconstructions=recons,
        pierced_reconstructions=pierced,
        pierced_correct=correct,
        first_ready_s=a.first_ready_s,
        grip=a.grip,
        trigger_s=moments.get("trigger"),
        take_over_s=moments.get("take_over"),
        sim_s=(a.end_ns - BASE_NS) / 1e9,
    )
    return outcome, carry


def run_block(
    config: TrialConfig,
    person: Person,
    block: int,
    seed: int,
    sequence: Sequence[tuple[str, float, float]] = PAPER_SEQUENCE,
    sink_for: Callable[[TrialSpec], Sink | None] | None = None,
    on_trial: Callable[[TrialOutcome], None] | None = None,
) -> list[TrialOutcome]:
    """One block: the sequence once, the hand carried from trial to trial (a block starts
    with the wrist neutral and the hand open, after the break)."""
    carry = fresh_carry(config)
    outcomes = []
    for index, (name, azimuth, elevation) in enumerate(sequence):
        spec = TrialSpec(
            user=person.index,
            block=block,
            index=index,
            object_name=name,
            azimuth_deg=azimuth,
            elevation_deg=elevation,
            practice=block * len(sequence) + index + 1,
            seed=seed,
        )
        sink = sink_for(spec) if sink_for is not None else None
        outcome, carry = run_trial(config, person, spec, carry, sink)
        outcomes.append(outcome)
        if on_trial is not None:
            on_trial(outcome)
    return outcomes


# --------------------------------------------------------------------------- statistics


def user_block_medians(
    outcomes: Sequence[TrialOutcome], users: Sequence[int], blocks: int
) -> np.ndarray:
    """(users, blocks) median TAT over each person's completed trials in each block (the
    paper's per-participant measure); NaN where a person completed none."""
    index = {u: i for i, u in enumerate(users)}
    cells: list[list[list[float]]] = [[[] for _ in range(blocks)] for _ in users]
    for o in outcomes:
        if o.completed and o.tat_s is not None and o.user in index and 0 <= o.block < blocks:
            cells[index[o.user]][o.block].append(o.tat_s)
    out = np.full((len(users), blocks), np.nan)
    for i, row in enumerate(cells):
        for b, values in enumerate(row):
            if values:
                out[i, b] = float(np.median(values))
    return out


def median_iqr(values: np.ndarray) -> tuple[float, float]:
    """Median and interquartile range of the finite values (NaN, NaN if none)."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return math.nan, math.nan
    q1, q2, q3 = np.percentile(finite, [25, 50, 75])
    return float(q2), float(q3 - q1)


@dataclass(frozen=True)
class Friedman:
    statistic: float
    p: float
    n: int
    # Post hoc: (block a, block b, Wilcoxon p, Bonferroni-corrected p), blocks 0-based.
    pairs: tuple[tuple[int, int, float, float], ...] = ()


def wilcoxon_p(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """Two-sided Wilcoxon signed-rank p of paired samples (NaN pairs dropped) and the pair
    count; p = 1 when every difference is zero, NaN with fewer than two pairs."""
    from scipy import stats

    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    keep = np.isfinite(a) & np.isfinite(b)
    a, b = a[keep], b[keep]
    n = int(keep.sum())
    if n < 2:
        return math.nan, n
    if np.all(a - b == 0):
        return 1.0, n
    return float(stats.wilcoxon(a, b).pvalue), n


def friedman(medians: np.ndarray) -> Friedman | None:
    """Friedman's test across blocks (columns) over the people complete in every block, with
    Bonferroni-corrected pairwise Wilcoxon tests (the paper's analysis); None for fewer than
    three blocks or two complete people."""
    from scipy import stats

    complete = medians[np.all(np.isfinite(medians), axis=1)]
    n, blocks = complete.shape
    if blocks < 3 or n < 2:
        return None
    statistic, p = stats.friedmanchisquare(*complete.T)
    m = blocks * (blocks - 1) // 2
    pairs = []
    for i in range(blocks):
        for j in range(i + 1, blocks):
            pw, _ = wilcoxon_p(complete[:, i], complete[:, j])
            pairs.append((i, j, pw, min(pw * m, 1.0) if math.isfinite(pw) else math.nan))
    return Friedman(float(statistic), float(p), n, tuple(pairs))


__all__ = [
    "PAPER_PERIOD_S",
    "PAPER_SEQUENCE",
    "PAPER_TAT_S",
    "Carry",
    "Friedman",
    "Person",
    "TrialConfig",
    "TrialOutcome",
    "TrialSpec",
    "fresh_carry",
    "friedman",
    "make_person",
    "median_iqr",
    "render_window",
    "run_block",
    "run_trial",
    "user_block_medians",
    "wilcoxon_p",
]
