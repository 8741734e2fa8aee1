"""Message types, one msgspec Struct per bus topic.

Every message carries ``seq`` (int64), ``t_ns`` (capture or event time, int64 ns since the
Unix epoch) and ``version``. Evolution follows msgspec's rules: new fields get defaults, and
existing fields are never reordered or retyped. Arrays travel as ``NDArray`` (bytes + dtype +
shape).
"""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta, Struct, field

Seq = Annotated[int, Meta(ge=0, le=2**63 - 1)]
TimeNs = Annotated[int, Meta(ge=0, le=2**63 - 1)]
Unit = Annotated[float, Meta(ge=0.0, le=1.0)]
ShapeName = Literal["sphere", "cylinder", "cuboid", "none"]
# A multi-grip hand's grips (lpc_core.perception.grip chooses one); a one-grip hand does power.
GripName = Literal["power", "tripod", "lateral", "pinch"]


class Message(Struct, kw_only=True, frozen=True):
    """Fields every topic carries.

    Messages derived from a depth frame (scans, reconstruction, grasp target, aim cue, tactor
    command) keep that frame's capture time in ``t_ns``: ``now - t_ns`` is the pipeline's
    latency, and staleness is measured from capture, not from arrival.
    """

    seq: Seq
    t_ns: TimeNs
    version: int = 1


class NDArray(Struct, frozen=True):
    """A numpy array on the wire: raw little-endian bytes, numpy dtype string and shape.

    Decoded, ``data`` is a read-only view into the payload, not a copy of it (a depth frame's
    200 KB copied on every decode); so a payload must be ``bytes``, which nothing can change
    while the message lives (``Topic.decode`` sees to it). Built here (``to_wire``), it holds
    ``bytes``: both have ``len``, ``==`` by content, and the buffer ``np.frombuffer`` reads.
    """

    data: memoryview
    dtype: Annotated[str, Meta(pattern=r"^(<f[248]|<[iu][248]|\|[iu]1|\|b1)$")]
    shape: list[Annotated[int, Meta(ge=0)]]


class CameraIntrinsics(Struct, frozen=True, kw_only=True):
    """Depth intrinsics with pyrealsense2's names; ``depth_scale`` is metres per unit."""

    width: Annotated[int, Meta(gt=0, le=4096)]
    height: Annotated[int, Meta(gt=0, le=4096)]
    fx: Annotated[float, Meta(gt=0)]
    fy: Annotated[float, Meta(gt=0)]
    ppx: float
    ppy: float
    model: str = "brown_conrady"
    coeffs: list[float] = []
    depth_scale: Annotated[float, Meta(gt=0)] = 0.001


class ObjectTruth(Struct, frozen=True, kw_only=True):
    """Ground truth of the aimed object, present only for simulated frames."""

    name: str
    shape: ShapeName
    grasp_width_mm: float
    wrist_angle_deg: float | None = None
    pierced: bool = False


class DepthFrame(Message, frozen=True, kw_only=True, tag="depth"):
    """``lpc/camera/depth``: one Z16 depth image, row-major uint16 (0 = no depth)."""

    intrinsics: CameraIntrinsics
    depth: NDArray
    source: str = "sim"
    truth: ObjectTruth | None = None


class ScanLine(Struct, frozen=True, kw_only=True):
    """The points of one scan line, (N, 3) float32 metres in the camera frame, sorted along it.

    ``past_ends_m``: the median depth (metres) of the image 8-30 px past the line's first and
    last point along it (two floats), 0 where no pixel there has depth; None where not
    measured (scans recorded before it was). ``far_past_m``: the point (metres, camera frame)
    of the first pixel past the line's first and last point along it whose depth lies beyond
    the capture volume (six floats: the first end's x, y, z, then the last end's), zeros
    where none does; None where not measured. ``edge_past_m``: where the line leaves the
    face its first and last point lie on, for an end at the capture volume's side (six
    floats as ``far_past_m``; ``lpc_core.perception.scans._edge_points``), zeros where it
    does not within 40 px; None where not measured.
    """

    angle_deg: float
    points: NDArray
    past_ends_m: list[float] | None = None
    far_past_m: list[float] | None = None
    edge_past_m: list[float] | None = None


class ScanLines(Message, frozen=True, kw_only=True, tag="scans"):
    """``lpc/scans``: the four scan lines cut from one depth frame (``t_ns`` = capture time)."""

    frame_seq: Seq
    lines: list[ScanLine]
    capture_points: int = 0
    truth: ObjectTruth | None = None


class LineModel(Struct, frozen=True, kw_only=True):
    """The 2-D model kept on one scan line, with ``lpc_core.perception.fit``'s ``params``."""

    angle_deg: float
    model: Literal["line", "circle", "ellipse", "none"]
    params: list[float] = []
    inlier_fraction: Unit = 0.0
    n_points: Annotated[int, Meta(ge=0)] = 0


class Reconstruction(Message, frozen=True, kw_only=True, tag="reconstruction"):
    """``lpc/reconstruction``: shape, size and orientation from one frame."""

    frame_seq: Seq
    method: Literal["laser", "cloud"] = "laser"
    shape: ShapeName
    grasp_width_mm: float | None = None
    wrist_angle_deg: float | None = None
    center_m: list[float] | None = None
    axis: list[float] | None = None
    lines: list[LineModel] = []
    confidence: Unit = 0.0
    reason: str = ""
    points: Annotated[int, Meta(ge=0)] = 0
    compute_ms: Annotated[float, Meta(ge=0)] = 0.0
    truth: ObjectTruth | None = None


class GraspTarget(Message, frozen=True, kw_only=True, tag="grasp_target"):
    """``lpc/grasp/target``: the 10-frame median window.

    ``reconstructed`` is the flag the controller waits for. ``grip`` is the grip the rule table
    of ``lpc_core.perception.grip`` chose for it, ``grip_reason`` why.
    """

    frame_seq: Seq
    shape: ShapeName
    grasp_width_mm: float | None = None
    wrist_angle_deg: float | None = None
    reconstructed: bool = False
    frames: Annotated[int, Meta(ge=0)] = 0
    agreement: Unit = 0.0
    grip: GripName = "power"
    grip_reason: str = ""


class AimCue(Message, frozen=True, kw_only=True, tag="aim_cue"):
    """``lpc/aim/cue``: which way to move so the optical axis pierces the object.

    ``rho`` is the distance to the hull over the capture width (clipped to 1), ``theta_deg``
    its direction in the image plane (x right, y down). ``amplitudes`` are the four tactors'.
    """

    frame_seq: Seq
    state: Literal["nothing", "guiding", "on_target", "ready"]
    rho: Unit = 1.0
    theta_deg: float = 0.0
    amplitudes: list[Unit] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    objects: Annotated[int, Meta(ge=0)] = 0


class TactorCommand(Message, frozen=True, kw_only=True, tag="tactor_command"):
    """``lpc/tactors/command``: amplitude 0–1 per tactor.

    ``pulse`` asks for the intermittent on-target pattern.
    """

    amplitudes: list[Unit]
    pulse: bool = False
    frequency_hz: Annotated[float, Meta(ge=0, le=4000)] = 250.0


class EmgSample(Message, frozen=True, kw_only=True, tag="emg"):
    """``lpc/emg``: one sample of the rectified EMG envelopes (flexor, extensor), raw units."""

    channels: list[float]
    unit: str = "V"
    source: str = "sim"


class ControllerState(Message, frozen=True, kw_only=True, tag="controller_state"):
    """``lpc/controller/state``: the controller's state, on every transition and at 10 Hz."""

    state: Literal["idle", "aiming", "ready", "preshaping", "direct", "stopped"]
    previous: str = ""
    event: str = ""
    reason: str = ""
    dof: Literal["grasp", "wrist"] = "grasp"
    target_width_mm: float | None = None
    target_angle_deg: float | None = None
    grip: GripName = "power"  # the grip pre-shaped for (or, before one, of the target)


class ProsthesisCommand(Message, frozen=True, kw_only=True, tag="prosthesis_command"):
    """``lpc/prosthesis/command``: velocity set-points, each in [-1, 1] of the hand's maximum.

    ``grasp`` > 0 closes the hand; ``wrist`` > 0 rotates toward positive wrist angle; a
    multi-grip hand closes in ``grip`` (a one-grip hand ignores it).
    """

    grasp: Annotated[float, Meta(ge=-1.0, le=1.0)]
    wrist: Annotated[float, Meta(ge=-1.0, le=1.0)]
    source: str = "controller"
    grip: GripName = "power"


class ProsthesisState(Message, frozen=True, kw_only=True, tag="prosthesis_state"):
    """``lpc/prosthesis/state``: what the hand reports, at 100 Hz."""

    wrist_angle_deg: float
    aperture_mm: float
    grip_force_pct: float = 0.0
    emg: list[float] = []
    hand: str = "sim"
    grip: GripName = "power"  # the grip the hand is making


class Health(Message, frozen=True, kw_only=True, tag="health"):
    """``lpc/health/<service>``: a service's counters, once a second.

    ``rates_hz`` per topic published, ``latency_ms`` as ``{"p50": .., "p99": ..}`` from capture
    time to publication, ``counters`` such as received, published, dropped, rejected.
    ``argv`` holds the service's command-line flags, so that a replay of a recording runs each
    step function with the parameters its service had.
    """

    service: str
    pid: int
    status: Literal["starting", "ok", "degraded", "stopping"] = "ok"
    rates_hz: dict[str, float] = {}
    latency_ms: dict[str, float] = {}
    counters: dict[str, int] = {}
    rss_bytes: int = 0
    detail: str = ""
    argv: list[str] = []


class Log(Message, frozen=True, kw_only=True, tag="log"):
    """``lpc/log/<service>``: a human-readable event, for dashboards."""

    service: str
    level: Literal["debug", "info", "warning", "error"] = "info"
    text: str
