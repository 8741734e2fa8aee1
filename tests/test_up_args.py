"""``lpc up``'s flags to the services it starts: the EMG source and the controller's
calibration (pure argv construction and validation; no process is started)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from lpc_core.control.emg import EmgProfile
from services.cli import up
from services.drivers.emg import save_emg_profile


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    up.add_arguments(parser)
    return parser.parse_args(list(argv))


def argv_of(name: str, args: argparse.Namespace) -> list[str]:
    return up.SERVICES[name].argv(args)


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    """A profile as ``lpc emg calibrate`` writes it, beside another section."""
    path = tmp_path / "profile.json"
    path.write_text(json.dumps({"tactors": {"arm": "left"}}))
    save_emg_profile(EmgProfile(rest=(0.01, 0.02), maximal=(0.9, 0.8), user="p1"), path)
    return path


def test_up_args_default_runs_the_scripted_user() -> None:
    args = parse("--seed", "3")
    assert up._validate(args) is None
    assert argv_of("emg", args) == ["--source", "sim", "--seed", "3"]
    assert argv_of("controller", args) == ["--sim-user", "--camera-fixed"]


def test_up_args_serial_emg_passes_the_port_and_the_profile(profile: Path) -> None:
    args = parse("--emg", "serial", "--emg-port", "/dev/ttyACM1", "--profile", str(profile))
    assert up._validate(args) is None
    assert argv_of("emg", args) == ["--source", "serial", "--port", "/dev/ttyACM1"]
    controller = argv_of("controller", args)
    assert "--sim-user" not in controller
    assert controller == ["--profile", str(profile), "--camera-fixed"]


def test_up_args_can_emg_passes_channel_and_interface(profile: Path) -> None:
    args = parse("--emg", "can", "--can-channel", "vcan0", "--profile", str(profile))
    assert up._validate(args) is None
    assert argv_of("emg", args) == ["--source", "can", "--can", "vcan0", "--interface", "socketcan"]
    args = parse(
        "--emg", "can", "--can-channel", "1", "--can-interface", "pcan", "--profile", str(profile)
    )
    assert argv_of("emg", args)[-2:] == ["--interface", "pcan"]


def test_up_args_real_emg_defaults_to_the_calibrated_profile(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Where 'lpc emg calibrate' writes by default (~ expanded).
    monkeypatch.setenv("HOME", str(tmp_path))
    args = parse("--emg", "serial", "--emg-port", "loop://")
    problem = up._validate(args)
    assert problem is not None
    assert "needs the user's EMG calibration" in problem and "lpc emg calibrate" in problem
    assert str(tmp_path / ".config/lpc/profile.json") in problem
    save_emg_profile(EmgProfile(), None)
    assert up._validate(args) is None
    expected = str(tmp_path / ".config/lpc/profile.json")
    assert argv_of("controller", args) == ["--profile", expected, "--camera-fixed"]


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (("--emg", "serial"), "--emg serial needs --emg-port"),
        (("--emg", "can"), "--emg can needs --can-channel"),
        (("--emg-port", "/dev/ttyUSB0"), "--emg-port does not apply to --emg sim"),
        (("--emg", "can", "--can-channel", "can0", "--emg-port", "x"), "does not apply"),
        (("--emg", "serial", "--emg-port", "x", "--can-channel", "can0"), "does not apply"),
        (("--profile", "p.json"), "--profile is for a real EMG"),
        (("--emg", "brainflow"), "--emg brainflow needs --board (e.g. --board cyton)"),
        (("--emg", "lsl", "--board", "cyton"), "--board does not apply to --emg lsl"),
        (("--emg", "lsl", "--board-config", "x"), "--board-config does not apply to --emg lsl"),
        (("--emg", "brainflow", "--board", "x", "--lsl-type", "EMG"), "does not apply"),
        (("--emg", "lsl", "--lsl-stream", "a", "--lsl-type", "EMG"), "alternatives"),
        (("--mains", "60"), "--mains does not apply to --emg sim"),
        (("--emg", "serial", "--emg-port", "x", "--mains", "60"), "--mains does not apply"),
        (("--emg-channels", "0,1"), "--emg-channels does not apply to --emg sim"),
    ],
)
def test_up_args_missing_or_stray_device_flags_are_clear_errors(
    argv: tuple[str, ...], needle: str
) -> None:
    problem = up._validate(parse(*argv))
    assert problem is not None and needle in problem


def test_up_args_profile_without_emg_section_or_missing_is_an_error(tmp_path: Path) -> None:
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps({"tactors": {}}))
    problem = up._validate(parse("--emg", "serial", "--emg-port", "x", "--profile", str(bare)))
    assert problem is not None and "no EMG calibration" in problem
    missing = tmp_path / "missing.json"
    problem = up._validate(parse("--emg", "serial", "--emg-port", "x", "--profile", str(missing)))
    assert problem is not None and "does not exist" in problem
    # Without the controller, nothing needs the calibration.
    args = parse("--emg", "serial", "--emg-port", "x", "--services", "emg", "recorder")
    assert up._validate(args) is None


def test_up_args_services_take_what_up_passes(
    profile: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Each service's own parser takes the argv (a stray flag would exit 2), and the controller
    # ends up with the calibrated profile, not the simulated user's.
    from services import controller, emg, runtime

    started: dict[str, argparse.Namespace] = {}

    def capture(name: str, serve: object, args: argparse.Namespace) -> int:
        started[name] = args
        return 0

    monkeypatch.setattr(emg, "run_service", capture)
    monkeypatch.setattr(runtime, "run_service", capture)  # the controller's, via service_main
    args = parse("--emg", "serial", "--emg-port", "loop://", "--profile", str(profile))
    assert emg.main(argv_of("emg", args)) == 0
    assert controller.main(argv_of("controller", args)) == 0
    assert started["emg"].source == "serial" and started["emg"].port == "loop://"
    params = controller.initial_state(started["controller"]).params
    assert params.profile.user == "p1"
    assert params.profile.maximal == pytest.approx((0.9, 0.8))
    assert not params.camera_on_hand
    args = parse("--emg", "can", "--can-channel", "vcan0", "--profile", str(profile))
    assert emg.main(argv_of("emg", args)) == 0
    assert (started["emg"].source, started["emg"].can) == ("can", "vcan0")
    assert emg.main(argv_of("emg", parse())) == 0
    assert controller.main(argv_of("controller", parse())) == 0
    assert started["emg"].source == "sim"
    assert controller.initial_state(started["controller"]).params.profile.user == "sim"


def test_up_args_lsl_and_brainflow_emg_pass_their_flags(profile: Path) -> None:
    args = parse("--emg", "lsl", "--lsl-stream", "Trigno", "--profile", str(profile))
    assert up._validate(args) is None
    assert argv_of("emg", args) == [
        "--source",
        "lsl",
        "--lsl-type",
        "EMG",
        "--lsl-stream",
        "Trigno",
    ]
    args = parse(
        *("--emg", "lsl", "--lsl-type", "EXG", "--lsl-scope", "machine", "--mains", "60"),
        *("--emg-channels", "2,5", "--profile", str(profile)),
    )
    assert up._validate(args) is None
    assert argv_of("emg", args) == [
        *("--source", "lsl", "--lsl-type", "EXG", "--lsl-scope", "machine"),
        *("--mains", "60", "--channels", "2", "5"),
    ]
    args = parse(
        *("--emg", "brainflow", "--board", "cyton", "--serial-port", "/dev/ttyUSB0"),
        *("--board-config", "x1060000X", "--profile", str(profile)),
    )
    assert up._validate(args) is None
    assert argv_of("emg", args) == [
        *("--source", "brainflow", "--board", "cyton", "--serial-port", "/dev/ttyUSB0"),
        *("--board-config", "x1060000X"),
    ]
    assert argv_of("controller", args)[:2] == ["--profile", str(profile)]


@pytest.mark.parametrize("text", ["0", "0,1,2", "a,b", "-1,0"])
def test_up_args_emg_channels_want_two_indices(text: str) -> None:
    with pytest.raises(SystemExit):
        parse("--emg", "lsl", "--emg-channels", text)


def test_up_args_raw_emg_flags_reach_the_emg_service(
    profile: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from services import emg

    started = {}
    monkeypatch.setattr(emg, "run_service", lambda name, serve, args: started.update(a=args) or 0)
    args = parse("--emg", "lsl", "--lsl-stream", "s", "--emg-channels", "1,0", "--mains", "60")
    assert emg.main([*argv_of("emg", args), "--lsl-scope", "machine"]) == 0
    got = started["a"]
    assert (got.source, got.lsl_stream, got.channels, got.mains) == ("lsl", "s", [1, 0], 60.0)
    assert got.unit == "raw"
    args = parse("--emg", "brainflow", "--board", "ganglion", "--serial-port", "/dev/ttyACM0")
    assert emg.main(argv_of("emg", args)) == 0
    got = started["a"]
    assert (got.source, got.board, got.serial_port, got.unit) == (
        "brainflow",
        "ganglion",
        "/dev/ttyACM0",
        "uV",
    )


def test_up_args_ability_hand_reaches_the_bridge(monkeypatch: pytest.MonkeyPatch) -> None:
    from services import prosthesis_bridge

    assert argv_of("prosthesis_bridge", parse()) == ["--sim-hand"]
    args = parse("--hand", "ability")
    assert up._validate(args) is None
    assert argv_of("prosthesis_bridge", args) == ["--sim-hand", "--hand", "ability"]
    args = parse("--hand", "ability", "--hand-port", "/dev/ttyUSB0")
    bridge_argv = argv_of("prosthesis_bridge", args)
    assert bridge_argv[-2:] == ["--hand-port", "/dev/ttyUSB0"]
    started: dict[str, argparse.Namespace] = {}
    monkeypatch.setattr(
        prosthesis_bridge, "run_service", lambda name, serve, a: started.setdefault(name, a) and 0
    )
    prosthesis_bridge.main(bridge_argv)
    bridge = started["prosthesis_bridge"]
    assert (bridge.hand, bridge.hand_port, bridge.sim_hand) == ("ability", "/dev/ttyUSB0", True)
    assert up._validate(parse("--hand-port", "/dev/ttyUSB0")) == "--hand-port is for --hand ability"


def test_up_args_hand_can_drives_a_hand_on_a_bus_instead_of_the_simulated_one() -> None:
    """--hand-can: the bridge opens the named python-can bus (a simulated hand as a device,
    ``hand_sim --ports-file``) and runs no simulated hand of its own."""
    args = parse("--hand-can", "serial:/dev/pts/7", "--tactor-port", "/dev/pts/8")
    assert up._validate(args) is None
    assert argv_of("prosthesis_bridge", args) == [
        "--interface",
        "serial",
        "--channel",
        "/dev/pts/7",
    ]
    assert argv_of("tactor_bridge", args)[-2:] == ["--tactor-port", "/dev/pts/8"]
    assert up._validate(parse("--hand-can", "/dev/pts/7")) is not None
    assert up._validate(parse("--hand", "ability", "--hand-can", "serial:/dev/pts/7")) == (
        "--hand-can is for --hand can"
    )


def test_up_args_together_one_container_and_the_bridge_apart() -> None:
    """--together: every service but the prosthesis bridge in one container child, in start
    order, the control path on its loop; each service's own main accepts the flags it gets."""
    from services.container import load_all

    args = parse("--together", "--record", "out.mcap")
    members = [
        up.Child(name, spec, spec.argv(args))
        for name, spec in up.SERVICES.items()
        if spec.enabled(args) and name not in up.APART
    ]
    child = up._container_child(args, members)
    assert child.spec.module == "services.container"
    specs = json.loads(child.argv[child.argv.index("--services") + 1])
    assert [s["module"] for s in specs] == [up.SERVICES[m.name].module for m in members]
    assert specs[0]["module"] == "services.recorder", "the recorder starts first"
    assert "services.prosthesis_bridge" not in [s["module"] for s in specs]
    on_control = {s["module"] for s in specs if s.get("loop") == "control"}
    assert on_control == {"services.emg", "services.controller", "services.tactor_bridge"}
    loaded = load_all(specs)
    assert [s.name for s in loaded] == [m.name for m in members]
    assert all(s.args.quiet for s in loaded)
    assert set(child.members) == {m.name for m in members}


def test_up_args_sim_device_source_passes_its_socket(monkeypatch: pytest.MonkeyPatch) -> None:
    from services import camera

    started: dict[str, argparse.Namespace] = {}
    monkeypatch.setattr(camera, "run_service", lambda name, serve, a: started.update(c=a) or 0)
    args = parse("--source", "sim-device", "/run/cam.sock")
    assert up._validate(args) is None
    assert camera.main(argv_of("camera", args)) == 0
    assert (started["c"].source, started["c"].socket) == ("sim-device", "/run/cam.sock")
    args = parse("--source", "sim-device")  # the device's default socket
    assert camera.main(argv_of("camera", args)) == 0
    assert started["c"].socket == camera.default_sim_socket()
    assert "sim, sim-device, realsense or replay" in (up._validate(parse("--source", "usb")) or "")


def test_up_args_no_shed_reaches_the_camera(monkeypatch: pytest.MonkeyPatch) -> None:
    from services import camera

    started: dict[str, argparse.Namespace] = {}
    monkeypatch.setattr(camera, "run_service", lambda name, serve, a: started.update(c=a) or 0)
    assert camera.main(argv_of("camera", parse())) == 0
    assert started["c"].shed
    assert camera.main(argv_of("camera", parse("--no-shed"))) == 0
    assert not started["c"].shed
