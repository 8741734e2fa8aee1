from __future__ import annotations

import itertools
import math

import msgspec
import numpy as np
import pytest

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
    Log,
    ProsthesisCommand,
    ProsthesisState,
    Reconstruction,
    ScanLine,
    ScanLines,
    TactorCommand,
    decode,
    encode,
    from_wire,
    json_schema,
    to_wire,
    to_wire_rows,
    topic_for_key,
)

INTR = CameraIntrinsics(width=4, height=3, fx=213.0, fy=213.0, ppx=2.0, ppy=1.5)

EXAMPLES = {
    "lpc/camera/depth": DepthFrame(
        seq=7,
        t_ns=1_700_000_000_000_000_000,
        intrinsics=INTR,
        depth=to_wire(np.arange(12, dtype=np.uint16).reshape(3, 4)),
    ),
    "lpc/scans": ScanLines(
        seq=7,
        t_ns=1,
        frame_seq=7,
        lines=[ScanLine(angle_deg=45.0, points=to_wire(np.ones((5, 3), np.float32)))],
    ),
    "lpc/reconstruction": Reconstruction(
        seq=1, t_ns=2, frame_seq=3, shape="cylinder", grasp_width_mm=40.0, wrist_angle_deg=30.0
    ),
    "lpc/grasp/target": GraspTarget(seq=1, t_ns=2, frame_seq=3, shape="sphere", reconstructed=True),
    "lpc/aim/cue": AimCue(seq=1, t_ns=2, frame_seq=3, state="guiding", rho=0.5, theta_deg=90.0),
    "lpc/tactors/command": TactorCommand(seq=1, t_ns=2, amplitudes=[0.5, 0.5, 0.0, 0.0]),
    "lpc/emg": EmgSample(seq=1, t_ns=2, channels=[0.1, 0.2]),
    "lpc/controller/state": ControllerState(seq=1, t_ns=2, state="aiming", reason="object seen"),
    "lpc/prosthesis/command": ProsthesisCommand(seq=1, t_ns=2, grasp=0.5, wrist=-0.25),
    "lpc/prosthesis/state": ProsthesisState(seq=1, t_ns=2, wrist_angle_deg=10, aperture_mm=50),
    "lpc/health/camera": Health(seq=1, t_ns=2, service="camera", pid=1, counters={"dropped": 0}),
    "lpc/log/camera": Log(seq=1, t_ns=2, service="camera", text="hello"),
}


def test_registry_covers_every_topic_once() -> None:
    keys = [t.key for t in TOPICS]
    assert len(keys) == len(set(keys))
    covered = {topic_for_key(k).key for k in EXAMPLES}
    assert covered == set(keys)


@pytest.mark.parametrize("key", sorted(EXAMPLES))
def test_schema_round_trip(key: str) -> None:
    message = EXAMPLES[key]
    assert decode(key, encode(message)) == message
    assert message.version == 1


@pytest.mark.parametrize("key", sorted(EXAMPLES))
def test_schema_json_schema_is_exported(key: str) -> None:
    schema = json_schema(topic_for_key(key).type)
    assert "$defs" in schema or "properties" in schema
    name = type(EXAMPLES[key]).__name__
    assert {"seq", "t_ns", "version"} <= set(schema["$defs"][name]["properties"])


def test_decode_rejects_malformed_payload() -> None:
    with pytest.raises(BadMessage, match="malformed"):
        decode("lpc/emg", b"\xc1\xff")


def test_decode_rejects_truncated_payload() -> None:
    payload = encode(EXAMPLES["lpc/emg"])
    with pytest.raises(BadMessage):
        decode("lpc/emg", payload[:-3])


def test_decode_rejects_wrong_type_and_limits() -> None:
    with pytest.raises(BadMessage, match="invalid"):
        decode("lpc/prosthesis/command", encode(EXAMPLES["lpc/emg"]))
    too_fast = msgspec.msgpack.encode({"seq": 1, "t_ns": 1, "grasp": 3.0, "wrist": 0.0})
    with pytest.raises(BadMessage, match="grasp"):
        decode("lpc/prosthesis/command", too_fast)
    with pytest.raises(BadMessage):
        decode("lpc/emg", msgspec.msgpack.encode({"seq": -1, "t_ns": 1, "channels": []}))


def test_decode_rejects_other_version() -> None:
    payload = msgspec.msgpack.encode({"seq": 1, "t_ns": 1, "version": 2, "channels": [0.0]})
    with pytest.raises(BadMessage, match="version 2"):
        decode("lpc/emg", payload)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_decode_rejects_non_finite(bad: float) -> None:
    payload = encode(EmgSample(seq=1, t_ns=1, channels=[0.0, bad]))
    with pytest.raises(BadMessage, match=r"channels\[1\]"):
        decode("lpc/emg", payload)


def _floats_poisoned(value: object, bad: float) -> list[object]:
    """Copies of ``value``, one for each float in it, with that float set to ``bad``."""
    if isinstance(value, float):
        return [bad]
    out: list[object] = []
    if isinstance(value, msgspec.Struct):
        for name in value.__struct_fields__:
            for item in _floats_poisoned(getattr(value, name), bad):
                out.append(msgspec.structs.replace(value, **{name: item}))
    elif isinstance(value, list | tuple):
        for i, element in enumerate(value):
            for item in _floats_poisoned(element, bad):
                out.append(type(value)([*value[:i], item, *value[i + 1 :]]))
    elif isinstance(value, dict):
        for k, element in value.items():
            out += [{**value, k: item} for item in _floats_poisoned(element, bad)]
    return out


@pytest.mark.parametrize("key", sorted(EXAMPLES))
def test_finite_check_finds_every_float(key: str) -> None:
    # The check built per type agrees with the generic walk wherever a float sits.
    from schemas.registry import _finite_check, _first_non_finite

    message = EXAMPLES[key]
    check = _finite_check(type(message))
    assert check(message)
    poisoned = [
        p for bad in (math.nan, math.inf, -math.inf) for p in _floats_poisoned(message, bad)
    ]
    assert len(poisoned) == 3 * len(_floats_poisoned(message, 0.0))
    for p in poisoned:
        assert _first_non_finite(p) is not None
        assert not check(p)


def test_finite_check_reaches_floats_in_lists_and_optional_fields() -> None:
    from schemas.registry import _finite_check

    rich = msgspec.structs.replace(
        EXAMPLES["lpc/reconstruction"], center_m=[0.0, 0.01, 0.2], axis=[0.0, 1.0, 0.0]
    )
    check = _finite_check(Reconstruction)
    assert check(rich)
    poisoned = _floats_poisoned(rich, math.nan)
    assert len(poisoned) == 2 + 3 + 3 + 2  # width, angle, centre, axis, confidence, compute_ms
    assert not any(check(p) for p in poisoned)


def test_decode_of_repeated_intrinsics_rejects_each_non_finite_one() -> None:
    # Frames repeat their intrinsics: one equal to the last that passed passes untested,
    # and one that differs from it only in a non-finite value is still tested and rejected.
    frame = EXAMPLES["lpc/camera/depth"]
    good = frame.intrinsics
    for bad in (math.nan, math.inf):
        for poisoned in (
            msgspec.structs.replace(good, coeffs=[*good.coeffs, bad]),
            msgspec.structs.replace(good, ppy=bad),
        ):
            for intrinsics, ok in (
                (good, True),
                (poisoned, False),
                (good, True),
                (poisoned, False),
            ):
                payload = encode(msgspec.structs.replace(frame, intrinsics=intrinsics))
                if ok:
                    assert decode("lpc/camera/depth", payload).intrinsics == good
                else:
                    with pytest.raises(BadMessage, match="non-finite value in field intrinsics"):
                        decode("lpc/camera/depth", payload)


def test_decode_rejects_oversized_payload() -> None:
    with pytest.raises(BadMessage, match="exceeds"):
        decode("lpc/emg", b"\x00" * (64 * 1024 + 1))


def test_decode_unknown_key_is_keyerror() -> None:
    with pytest.raises(KeyError, match="no schema"):
        decode("lpc/nope", b"")


def test_topic_wildcards_match_one_level() -> None:
    assert topic_for_key("lpc/health/scans").type is Health
    with pytest.raises(KeyError):
        topic_for_key("lpc/health/a/b")
    with pytest.raises(KeyError):
        topic_for_key("lpc/health/")


def test_array_round_trip_and_checks() -> None:
    a = np.linspace(0, 1, 12, dtype=np.float32).reshape(4, 3)
    b = from_wire(to_wire(a))
    assert b.dtype == np.float32 and b.shape == (4, 3)
    np.testing.assert_array_equal(a, b)
    big_endian = a.astype(">f4")
    np.testing.assert_array_equal(from_wire(to_wire(big_endian)), a)
    wire = to_wire(a)
    short = msgspec.structs.replace(wire, data=wire.data[:-4])
    with pytest.raises(ValueError, match="44 bytes, expected 48"):
        from_wire(short)
    with pytest.raises(ValueError, match="NaN"):
        from_wire(to_wire(np.array([np.nan], np.float32)))


def test_rows_on_the_wire_are_each_slice_on_the_wire() -> None:
    # The scans' four lines: empty ones, a big-endian source, and the bytes each slice encodes.
    a = np.arange(7 * 3, dtype=np.float32).reshape(7, 3) / 7
    bounds = [0, 0, 2, 2, 7]
    for source in (a, a.astype(">f4")):
        rows = to_wire_rows(source, bounds)
        assert [r.shape for r in rows] == [[0, 3], [2, 3], [0, 3], [5, 3]]
        assert [msgspec.msgpack.encode(r) for r in rows] == [
            msgspec.msgpack.encode(to_wire(a[i:j])) for i, j in itertools.pairwise(bounds)
        ]
    np.testing.assert_array_equal(from_wire(to_wire_rows(a, [2, 5])[0]), a[2:5])


def test_array_dtype_pattern_is_validated() -> None:
    frame = msgspec.msgpack.encode({"data": b"", "dtype": "object", "shape": [0]})
    with pytest.raises(msgspec.ValidationError):
        msgspec.msgpack.decode(frame, type=type(to_wire(np.zeros(1))))


def test_bad_message_survives_pickling_with_its_fields() -> None:
    # It crosses process boundaries: the reconstructor's workers raise it.
    import pickle

    again = pickle.loads(pickle.dumps(BadMessage("lpc/scans", "truncated")))
    assert isinstance(again, BadMessage)
    assert (again.key, again.reason, str(again)) == (
        "lpc/scans",
        "truncated",
        "lpc/scans: truncated",
    )


def _depth_payload(offset: int) -> bytes:
    depth = (np.arange(240 * 424, dtype=np.uint16) + offset).reshape(240, 424)
    return encode(DepthFrame(seq=1, t_ns=2, intrinsics=INTR, depth=to_wire(depth)))


def test_decoded_array_views_its_payload_without_a_copy() -> None:
    # A depth frame's 200 KB were copied out of the payload on every decode (main: a copy,
    # shares_memory False).
    payload = _depth_payload(0)
    frame = decode("lpc/camera/depth", payload)
    depth = from_wire(frame.depth)
    assert np.shares_memory(depth, np.frombuffer(payload, np.uint8))
    assert not depth.flags.writeable
    np.testing.assert_array_equal(depth.ravel(), np.arange(240 * 424, dtype=np.uint16))
    assert encode(frame) == payload


def test_decoded_array_is_not_changed_by_its_buffer_being_reused() -> None:
    # A payload in a buffer that its owner refills (a receive or read buffer) is copied once:
    # the decoded frame must not view the buffer, nor hold it against a resize.
    buffer = bytearray(_depth_payload(0))
    frame = decode("lpc/camera/depth", memoryview(buffer))
    buffer[:] = _depth_payload(7)
    del buffer[:100]
    np.testing.assert_array_equal(
        from_wire(frame.depth).ravel(), np.arange(240 * 424, dtype=np.uint16)
    )
