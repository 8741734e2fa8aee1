"""Bad input: every topic decoder and every ``lpc_core`` entry point, fed garbage by hypothesis,
raises nothing but ``ValueError`` (``BadMessage`` is one) and never returns NaN or inf; the
``lpc`` command answers wrong parameters and corrupt files with one clear line and exit code 2.

Hypothesis runs a bounded number of examples per property (``EXAMPLES``) with the database off,
so a run is reproducible and fast; raise ``LPC_HYPOTHESIS_EXAMPLES`` for a deeper search.
"""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas import (
    TOPICS,
    AimCue,
    BadMessage,
    CameraIntrinsics,
    ControllerState,
    DepthFrame,
    EmgSample,
    GraspTarget,
    Health,
    LineModel,
    Log,
    NDArray,
    ProsthesisCommand,
    ProsthesisState,
    Reconstruction,
    ScanLine,
    ScanLines,
    TactorCommand,
    decode,
    encode,
    from_wire,
    to_wire,
    topic_for_key,
)

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = int(os.environ.get("LPC_HYPOTHESIS_EXAMPLES", "60"))
SETTINGS = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
VALID_DTYPES = ("<f4", "<f8", "<u2", "<i2", "<i4", "<u1", "|u1", "|i1", "|b1", "<i8", "<u8")


# --------------------------------------------------------------------------- helpers


def non_finite(value: Any, path: str = "", depth: int = 0) -> str | None:
    """The path of the first NaN or inf in an output (structs, dataclasses, arrays, containers)."""
    if depth > 12:
        return None
    if isinstance(value, bool | int | str | bytes | None):
        return None
    if isinstance(value, float | np.floating):
        return None if math.isfinite(value) else path or "<value>"
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc" and not np.isfinite(value).all():
            return path or "<array>"
        return None
    if isinstance(value, msgspec.Struct):
        items = [(n, getattr(value, n)) for n in value.__struct_fields__]
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        items = [(f.name, getattr(value, f.name)) for f in dataclasses.fields(value)]
    elif isinstance(value, dict):
        items = [(str(k), v) for k, v in value.items()]
    elif isinstance(value, list | tuple):
        items = [(str(i), v) for i, v in enumerate(value)]
    else:
        return None
    for name, item in items:
        found = non_finite(item, f"{path}.{name}" if path else name, depth + 1)
        if found is not None:
            return found
    return None


def _points(n: int = 20) -> NDArray:
    t = np.linspace(-0.02, 0.02, n)
    return to_wire(np.column_stack([t, 0 * t, 0.2 + 0 * t]).astype(np.float32))


def _intrinsics(width: int = 424, height: int = 240) -> CameraIntrinsics:
    return CameraIntrinsics(width=width, height=height, fx=213.0, fy=213.0, ppx=212.0, ppy=120.0)


EXAMPLE_MESSAGES: dict[str, Any] = {
    "lpc/camera/depth": DepthFrame(
        seq=1,
        t_ns=10,
        intrinsics=_intrinsics(8, 4),
        depth=to_wire(np.full((4, 8), 200, np.uint16)),
    ),
    "lpc/scans": ScanLines(
        seq=1,
        t_ns=10,
        frame_seq=1,
        lines=[ScanLine(angle_deg=a, points=_points()) for a in (0.0, 45.0, 90.0, 135.0)],
    ),
    "lpc/reconstruction": Reconstruction(
        seq=1,
        t_ns=10,
        frame_seq=1,
        shape="sphere",
        grasp_width_mm=60.0,
        center_m=[0.0, 0.0, 0.2],
        lines=[LineModel(angle_deg=0.0, model="circle", params=[0.0, 0.2, 0.03])],
    ),
    "lpc/grasp/target": GraspTarget(
        seq=1, t_ns=10, frame_seq=1, shape="cylinder", grasp_width_mm=60.0, wrist_angle_deg=10.0
    ),
    "lpc/aim/cue": AimCue(seq=1, t_ns=10, frame_seq=1, state="guiding", rho=0.5, theta_deg=30),
    "lpc/tactors/command": TactorCommand(seq=1, t_ns=10, amplitudes=[0.1, 0.2, 0.0, 0.0]),
    "lpc/emg": EmgSample(seq=1, t_ns=10, channels=[0.1, 0.2]),
    "lpc/controller/state": ControllerState(seq=1, t_ns=10, state="aiming", target_width_mm=5.0),
    "lpc/prosthesis/command": ProsthesisCommand(seq=1, t_ns=10, grasp=0.5, wrist=-0.5),
    "lpc/prosthesis/state": ProsthesisState(
        seq=1, t_ns=10, wrist_angle_deg=0.0, aperture_mm=50.0, emg=[1.0, 2.0]
    ),
    "lpc/health/scans": Health(
        seq=1, t_ns=10, service="scans", pid=1, rates_hz={"lpc/scans": 90.0}, latency_ms={}
    ),
    "lpc/log/scans": Log(seq=1, t_ns=10, service="scans", text="hello"),
}


def test_examples_cover_every_topic() -> None:
    assert {topic_for_key(k).key for k in EXAMPLE_MESSAGES} == {t.key for t in TOPICS}
    for key, message in EXAMPLE_MESSAGES.items():
        assert decode(key, encode(message)) == message


KEYS = sorted(EXAMPLE_MESSAGES)

# Any msgpack value: what a hostile or broken peer can put in a field.
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
    st.binary(max_size=40),
)
msgpack_values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=8), inner, max_size=5)
    ),
    max_leaves=12,
)


def _builtins(message: Any) -> Any:
    return msgspec.to_builtins(message, builtin_types=(bytes,))


def _check_decoded(key: str, payload: bytes) -> None:
    """Decoding either fails with a ValueError or gives a finite, version-1 message."""
    try:
        message = decode(key, payload)
    except BadMessage as exc:
        assert str(exc).startswith(key), "the reason names the topic"
        return
    except ValueError:
        # Invalid UTF-8 in a string escapes as UnicodeDecodeError (a ValueError, but not a
        # BadMessage): see test_decoders_reject_invalid_utf8_as_bad_message.
        return
    assert message.version == 1
    assert non_finite(message) is None
    assert decode(key, encode(message)) == message


# --------------------------------------------------------------------------- decoders


@SETTINGS
@given(key=st.sampled_from(KEYS), payload=st.binary(max_size=300))
def test_decoders_reject_random_bytes(key: str, payload: bytes) -> None:
    _check_decoded(key, payload)


@SETTINGS
@given(key=st.sampled_from(KEYS), data=st.data())
def test_decoders_reject_garbage_fields(key: str, data: st.DataObject) -> None:
    # A valid message with some fields replaced by anything msgpack can carry, some dropped
    # and some added: the validation paths, not just the parser.
    fields = _builtins(EXAMPLE_MESSAGES[key])
    names = sorted(fields)
    for name in data.draw(st.lists(st.sampled_from(names), max_size=4, unique=True)):
        fields[name] = data.draw(msgpack_values)
    for name in data.draw(st.lists(st.sampled_from(names), max_size=2, unique=True)):
        fields.pop(name, None)
    fields.update(data.draw(st.dictionaries(st.text(max_size=6), msgpack_values, max_size=2)))
    _check_decoded(key, msgspec.msgpack.encode(fields))


@SETTINGS
@given(key=st.sampled_from(KEYS), data=st.data())
def test_decoders_reject_flipped_bytes(key: str, data: st.DataObject) -> None:
    payload = bytearray(encode(EXAMPLE_MESSAGES[key]))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    _check_decoded(key, bytes(payload))


def test_decoders_reject_invalid_utf8_as_bad_message() -> None:
    payload = encode(EXAMPLE_MESSAGES["lpc/log/scans"]).replace(b"hello", b"\x80ello")
    with pytest.raises(BadMessage):
        decode("lpc/log/scans", payload)


@pytest.mark.parametrize("key", KEYS)
def test_decoders_reject_truncated_payloads(key: str) -> None:
    payload = encode(EXAMPLE_MESSAGES[key])
    cuts = sorted({*range(0, len(payload), max(1, len(payload) // 50)), len(payload) - 1})
    for cut in cuts:
        with pytest.raises(BadMessage):
            decode(key, payload[:cut])


@pytest.mark.parametrize("key", KEYS)
def test_decoders_reject_oversized_payloads(key: str) -> None:
    limit = topic_for_key(key).max_bytes
    with pytest.raises(BadMessage, match="exceeds"):
        decode(key, encode(EXAMPLE_MESSAGES[key]) + b"\0" * limit)


@pytest.mark.parametrize("key", KEYS)
def test_decoders_reject_other_versions(key: str) -> None:
    for version in (0, 2, -1, 2**40):
        fields = _builtins(EXAMPLE_MESSAGES[key])
        fields["version"] = version
        with pytest.raises(BadMessage, match="version"):
            decode(key, msgspec.msgpack.encode(fields))


def _float_paths(value: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    if isinstance(value, float):
        yield path
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from _float_paths(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _float_paths(v, (*path, i))


@pytest.mark.parametrize("key", KEYS)
def test_decoders_reject_nan_and_inf_in_every_float_field(key: str) -> None:
    fields = _builtins(EXAMPLE_MESSAGES[key])
    paths = list(_float_paths(fields))
    assert paths or key == "lpc/log/scans"
    for path in paths:
        for bad in (math.nan, math.inf, -math.inf):
            broken = _builtins(EXAMPLE_MESSAGES[key])
            target = broken
            for step in path[:-1]:
                target = target[step]
            target[path[-1]] = bad
            with pytest.raises(BadMessage):
                decode(key, msgspec.msgpack.encode(broken))


def test_decoders_reject_unknown_keys() -> None:
    for key in ("lpc/unknown", "lpc/health", "lpc/health/a/b", "other/camera/depth"):
        with pytest.raises(KeyError):
            decode(key, encode(EXAMPLE_MESSAGES["lpc/emg"]))


# --------------------------------------------------------------------------- arrays


ndarrays = st.builds(
    NDArray,
    data=st.binary(max_size=400),
    dtype=st.sampled_from(VALID_DTYPES),
    shape=st.lists(st.integers(0, 2**40), max_size=3),
)


@SETTINGS
@given(array=ndarrays)
def test_from_wire_rejects_inconsistent_arrays(array: NDArray) -> None:
    try:
        out = from_wire(array)
    except ValueError:
        return
    assert out.nbytes == len(array.data)
    assert non_finite(out) is None


def test_from_wire_rejects_dtypes_numpy_does_not_know() -> None:
    for dtype in ("<b8", "<f1", "|b2"):
        array = decode("lpc/scans", encode(EXAMPLE_MESSAGES["lpc/scans"]))
        wire = msgspec.structs.replace(array.lines[0].points, dtype=dtype)
        with pytest.raises(ValueError):
            from_wire(wire)


# --------------------------------------------------------------------------- lpc_core


def _finite_floats(lo: float = -1e3, hi: float = 1e3) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


# Points reach the fits through float32 on the wire: beyond that range (about 1e154 squared)
# the fits overflow with OverflowError (reported, perception/fit.py), which the bus cannot send.
any_floats = st.floats(allow_nan=True, allow_infinity=True, width=32)
point_sets = st.one_of(
    # Plausible scan-line points, some duplicated, some far away.
    st.integers(0, 60).flatmap(
        lambda n: st.lists(
            st.tuples(_finite_floats(-0.1, 0.1), _finite_floats(0.0, 0.4)), min_size=n, max_size=n
        )
    ),
    # Anything, including NaN, inf and huge values.
    st.lists(st.tuples(any_floats, any_floats), max_size=20),
)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # overflow on huge coordinates is expected
@SETTINGS
@given(points=point_sets, threshold=_finite_floats(0.0, 0.01), seed=st.integers(0, 2**32))
def test_fits_give_a_fit_or_a_failure_on_any_points(
    points: list[tuple[float, float]], threshold: float, seed: int
) -> None:
    from lpc_core.perception.fit import fit_circle, fit_ellipse, fit_line

    arr = np.array(points, dtype=np.float64).reshape(-1, 2)
    for fit in (fit_line, fit_circle, fit_ellipse):
        kwargs: dict[str, Any] = {"seed": seed, "max_trials": 50, "min_trials": 10}
        try:
            result = fit(arr, threshold, **kwargs)
        except ValueError:
            assert not np.isfinite(arr).all() or threshold <= 0
            continue
        assert non_finite(result.params) is None, (fit.__name__, result)
        if result:
            assert result.inliers.shape == (len(arr),)


@SETTINGS
@given(
    shape=st.lists(st.integers(0, 5), min_size=0, max_size=3), dtype=st.sampled_from(VALID_DTYPES)
)
def test_fits_reject_wrong_shapes(shape: list[int], dtype: str) -> None:
    from lpc_core.perception.fit import fit_circle, fit_ellipse, fit_line

    arr = np.zeros(shape, dtype=np.dtype(dtype))
    if arr.ndim == 2 and arr.shape[1] == 2:
        return
    for fit in (fit_line, fit_circle, fit_ellipse):
        with pytest.raises(ValueError):
            fit(arr, 0.001)


intrinsics_msgs = st.builds(
    CameraIntrinsics,
    width=st.integers(1, 64),
    height=st.integers(1, 64),
    fx=_finite_floats(1e-3, 1e4),
    fy=_finite_floats(1e-3, 1e4),
    ppx=_finite_floats(-1e3, 1e3),
    ppy=_finite_floats(-1e3, 1e3),
    depth_scale=_finite_floats(1e-6, 1.0),
)


@SETTINGS
@given(data=st.data())
def test_scans_step_rejects_frames_of_the_wrong_size(data: st.DataObject) -> None:
    from lpc_core.perception.pipeline import ScansState, scans_step

    intrinsics = data.draw(intrinsics_msgs)
    h, w = intrinsics.height, intrinsics.width
    kind = data.draw(st.sampled_from(["right", "shape", "dtype", "bytes"]))
    if kind == "right":
        depth = to_wire(
            np.frombuffer(data.draw(st.binary(min_size=2 * h * w, max_size=2 * h * w)), "<u2")
            .reshape(h, w)
            .copy()
        )
    elif kind == "shape":
        depth = to_wire(np.zeros((h + data.draw(st.integers(1, 3)), w), np.uint16))
    elif kind == "dtype":
        depth = to_wire(np.zeros((h, w), np.dtype(data.draw(st.sampled_from(VALID_DTYPES)))))
    else:
        depth = data.draw(ndarrays)
    frame = DepthFrame(seq=1, t_ns=1, intrinsics=intrinsics, depth=depth)
    try:
        _, out = scans_step(ScansState(), frame, 0)
    except ValueError:
        assert kind != "right"
        return
    assert non_finite(out) is None
    for line in out.lines:
        assert non_finite(from_wire(line.points)) is None


def test_cut_scan_lines_rejects_wrong_frames() -> None:
    from lpc_core.perception.intrinsics import Intrinsics
    from lpc_core.perception.scans import cut_scan_lines

    intrinsics = Intrinsics(width=424, height=240, fx=213.0, fy=213.0, ppx=212.0, ppy=120.0)
    for depth in (
        np.zeros((240, 423), np.uint16),
        np.zeros((424, 240), np.uint16),
        np.zeros((240, 424, 1), np.uint16),
        np.zeros(240 * 424, np.uint16),
    ):
        with pytest.raises(ValueError):
            cut_scan_lines(depth, intrinsics)


line_points = st.one_of(
    st.builds(
        lambda xs: to_wire(np.array(xs, np.float32).reshape(-1, 3)),
        st.lists(
            st.tuples(_finite_floats(-0.1, 0.1), _finite_floats(-0.1, 0.1), _finite_floats(0, 0.4)),
            max_size=40,
        ),
    ),
    ndarrays,
)
scan_messages = st.builds(
    ScanLines,
    seq=st.integers(0, 2**40),
    t_ns=st.integers(0, 2**62),
    frame_seq=st.integers(0, 2**40),
    lines=st.lists(
        st.builds(ScanLine, angle_deg=_finite_floats(-360, 360), points=line_points), max_size=5
    ),
)


@SETTINGS
@given(scans=scan_messages)
def test_aim_step_on_any_scan_lines(scans: ScanLines) -> None:
    from lpc_core.control.aim import AimState, aim_step

    try:
        _, outputs = aim_step(AimState(), scans, 0)
    except ValueError:
        return
    assert non_finite(outputs) is None


@SETTINGS
@given(scans=scan_messages, seed=st.integers(0, 2**31))
def test_reconstruct_laser_on_any_scan_lines(scans: ScanLines, seed: int) -> None:
    from lpc_core.perception.laser import reconstruct_laser

    class Lines:
        def __init__(self, message: ScanLines) -> None:
            self.angles_rad = np.radians([ln.angle_deg for ln in message.lines])
            self.points = [from_wire(ln.points) for ln in message.lines]

    try:
        lines = Lines(scans)
        result = reconstruct_laser(lines, seed=seed)
    except ValueError:
        return
    assert non_finite(result) is None
    if result.shape == "none":
        assert result.reason


targets = st.builds(
    GraspTarget,
    seq=st.integers(0, 2**40),
    t_ns=st.integers(0, 2**62),
    frame_seq=st.integers(0, 2**40),
    shape=st.sampled_from(["sphere", "cylinder", "cuboid", "none"]),
    grasp_width_mm=st.one_of(st.none(), _finite_floats(-1e6, 1e6)),
    wrist_angle_deg=st.one_of(st.none(), _finite_floats(-1e6, 1e6)),
    reconstructed=st.booleans(),
)


@SETTINGS
@given(target=targets)
def test_aim_step_on_any_grasp_target(target: GraspTarget) -> None:
    from lpc_core.control.aim import AimState, aim_step

    state, outputs = aim_step(AimState(), target, 0)
    assert outputs == []
    _, outputs = aim_step(state, EXAMPLE_MESSAGES["lpc/scans"], 0)
    assert non_finite(outputs) is None


emg_channels = st.lists(any_floats, min_size=0, max_size=4)


@SETTINGS
@given(samples=st.lists(st.tuples(emg_channels, st.integers(-(2**40), 2**62)), max_size=40))
def test_intent_step_on_any_samples(samples: list[tuple[list[float], int]]) -> None:
    from lpc_core.control.emg import IntentState, intent_step

    state = IntentState()
    for channels, t_ns in samples:
        try:
            state, intent = intent_step(state, channels, t_ns)
        except ValueError:
            assert len(channels) < 2
            continue
        assert non_finite(intent) is None
        assert -1.0 <= intent.velocity <= 1.0


controller_messages = st.one_of(
    st.builds(
        EmgSample,
        seq=st.integers(0, 100),
        t_ns=st.integers(0, 2**40),
        channels=st.lists(_finite_floats(-1e6, 1e6), max_size=4),
    ),
    targets,
    st.builds(
        AimCue,
        seq=st.integers(0, 100),
        t_ns=st.integers(0, 2**40),
        frame_seq=st.integers(0, 100),
        state=st.sampled_from(["nothing", "guiding", "on_target", "ready"]),
        rho=_finite_floats(0, 1),
        theta_deg=_finite_floats(-1e4, 1e4),
    ),
    st.builds(
        ProsthesisState,
        seq=st.integers(0, 100),
        t_ns=st.integers(0, 2**40),
        wrist_angle_deg=_finite_floats(-1e6, 1e6),
        aperture_mm=_finite_floats(-1e6, 1e6),
        grip_force_pct=_finite_floats(-1e6, 1e6),
    ),
)


@SETTINGS
@given(
    steps=st.lists(
        st.tuples(st.one_of(controller_messages, st.just(None)), st.integers(0, 300_000_000)),
        max_size=30,
    )
)
def test_controller_step_on_any_message_sequence(steps: list[tuple[Any, int]]) -> None:
    from lpc_core.control.controller import ControllerCore, Tick, TransitionError, controller_step

    core, now = ControllerCore(), 1_000_000_000
    for message, dt in steps:
        now += dt
        try:
            core, outputs = controller_step(core, message or Tick(now), now)
        except (ValueError, TransitionError):
            # TransitionError: the table has no entry; the service counts it and keeps ``core``.
            continue
        assert non_finite(outputs) is None
        for out in outputs:
            if isinstance(out, ProsthesisCommand):
                assert -1.0 <= out.grasp <= 1.0 and -1.0 <= out.wrist <= 1.0
                # Decodable by the bridge: what the controller sends passes the schema.
                decode("lpc/prosthesis/command", encode(out))


@SETTINGS
@given(
    events=st.lists(
        st.tuples(
            st.one_of(
                st.none(),
                st.builds(
                    TactorCommand,
                    seq=st.integers(0, 100),
                    t_ns=st.integers(0, 2**40),
                    amplitudes=st.lists(_finite_floats(0, 1), max_size=6),
                    pulse=st.booleans(),
                    frequency_hz=_finite_floats(0, 4000),
                ),
            ),
            st.integers(0, 10**9),
        ),
        max_size=20,
    )
)
def test_tactor_bridge_step_on_any_commands(events: list[tuple[Any, int]]) -> None:
    from lpc_core.devices.tactor_bridge import TICK, BridgeState, bridge_step

    state, now = BridgeState(), 0
    for event, dt in events:
        now += dt
        try:
            state, outputs = bridge_step(state, event or TICK, now)
        except ValueError:
            continue
        assert non_finite(outputs) is None


@SETTINGS
@given(
    frames=st.lists(
        st.tuples(
            st.sampled_from(["sphere", "cylinder", "cuboid", "none"]),
            st.one_of(st.none(), _finite_floats(0, 1)),
            st.one_of(st.none(), _finite_floats(-10, 10)),
            st.integers(-5, 20),
            st.integers(0, 10**9),
        ),
        max_size=25,
    )
)
def test_window_step_on_any_reconstructions(frames: list[tuple[Any, ...]]) -> None:
    from lpc_core.perception.reconstruction import Reconstruction as Core
    from lpc_core.perception.window import WindowState, window_step

    state, seq, t_ns = WindowState(), 0, 0
    for shape, width, angle, dseq, dt in frames:
        seq, t_ns = seq + dseq, t_ns + dt
        rec = Core(shape=shape, grasp_width_m=width, wrist_angle_rad=angle)
        state, result = window_step(state, rec, seq, t_ns)
        assert non_finite(result) is None
        assert 1 <= result.frames <= state.params.size


# --------------------------------------------------------------------------- the lpc command


def _lpc(*argv: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    # Commands whose table entry the lead has not added yet are added here for the run.
    code = (
        "import sys\n"
        "from services.cli import COMMANDS, main\n"
        "COMMANDS.setdefault('reconstruct', ('services.cli.reconstruct', ''))\n"
        "COMMANDS.setdefault('certs', ('services.cli.certs', ''))\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code, *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )


@pytest.fixture(scope="module")
def corrupt_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("corrupt")
    files = {
        "png": out / "corrupt.png",
        "png_head": out / "truncated.png",
        "mcap": out / "corrupt.mcap",
        "empty": out / "empty.mcap",
        "text": out / "notes.mcap",
    }
    files["png"].write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    files["png_head"].write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\1\xa8")
    files["mcap"].write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    files["empty"].write_bytes(b"")
    files["text"].write_text("this is not a recording\n")
    return files


BAD_COMMANDS: list[tuple[str, ...]] = [
    ("up", "--duration", "-1"),
    ("up", "--duration", "abc"),
    ("up", "--rate", "0"),
    ("up", "--source", "replay"),
    ("up", "--source", "floppy"),
    ("up", "--services", "teleporter"),
    ("up", "--port", "70000"),
    ("echo", "notlpc"),
    ("echo", "lpc/emg", "--count", "x"),
    ("info", "missing.mcap"),
    ("info", "{empty}"),
    ("info", "{text}"),
    ("reconstruct", "{png}"),
    ("reconstruct", "{png_head}"),
    ("reconstruct", "missing.png"),
    ("reconstruct", "{mcap}"),
    ("replay", "missing.mcap"),
    ("replay", "{mcap}"),
    ("export", "{text}", "--foxglove", "{out}"),
    ("certs", "make"),
    ("certs", "make", "{out}", "--days", "0"),
    ("bench", "nosuchbench"),
    ("nosuchcommand",),
    (),
]


def test_info_reports_a_corrupt_recording_as_cut(corrupt_files: dict[str, Path]) -> None:
    # A valid magic followed by garbage reads as a recording cut at its first record.
    result = _lpc("info", str(corrupt_files["mcap"]))
    assert "Traceback" not in result.stderr
    assert "CUT SHORT" in result.stdout and "no message before the cut" in result.stdout


def test_up_rejects_a_duration_of_nan() -> None:
    import argparse

    from services.cli import up

    parser = argparse.ArgumentParser()
    up.add_arguments(parser)
    assert up._validate(parser.parse_args(["--duration", "nan"])) is not None


def test_bad_commands_cover_the_kinds_of_error() -> None:
    commands = {c[0] for c in BAD_COMMANDS if c}
    assert {"up", "echo", "info", "reconstruct", "replay"} <= commands


@pytest.mark.parametrize("argv", BAD_COMMANDS, ids=lambda a: " ".join(a) or "(none)")
def test_lpc_rejects_wrong_parameters_with_exit_2(
    argv: tuple[str, ...], corrupt_files: dict[str, Path], tmp_path: Path
) -> None:
    names = {k: str(v) for k, v in corrupt_files.items()} | {"out": str(tmp_path / "out")}
    result = _lpc(*(a.format(**names) for a in argv), cwd=tmp_path)
    message = result.stderr.strip()
    assert result.returncode == 2, (result.returncode, message)
    assert "Traceback" not in result.stderr, message
    assert message, "a clear message on stderr"
    assert "error" in message.lower() or "usage" in message.lower(), message


def test_cli_stops_quietly_when_its_reader_goes_away(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``lpc schemas | head -1``: the pipe closes under the command, which stops with the
    pipe's status (141), not a traceback."""
    from services.cli import main

    sink = open(tmp_path / "sink", "w")  # noqa: SIM115 - its descriptor is redirected

    class ClosedPipe:
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self) -> None:
            raise BrokenPipeError(32, "Broken pipe")

        def fileno(self) -> int:
            return sink.fileno()

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    try:
        assert main(["schemas"]) == 141
    finally:
        sink.close()
