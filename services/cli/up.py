"""``lpc up``: start the service set as separate processes on one bus, show their status, stop
them cleanly.

The supervisor's own Zenoh session is the rendezvous every service connects to (gossip makes
the rest of the mesh). It watches liveliness tokens to know who is up, restarts a crashed
service with backoff, and stops services in reverse start order so that the recorder, started
first, is stopped last and loses nothing.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from schemas import Health, decode
from services.children import die_with_parent
from services.drivers.depth_flags import (
    add_realsense_arguments,
    add_sensor_arguments,
    realsense_argv,
    sensor_argv,
    stereo_sensor,
)
from services.runtime import zenoh_config

STOP_GRACE_S = 2.0
START_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class ServiceSpec:
    """How ``lpc up`` starts one service: its module, its flags, and when it runs at all."""

    module: str
    argv: Callable[[argparse.Namespace], list[str]] = lambda args: []
    enabled: Callable[[argparse.Namespace], bool] = lambda args: True
    # Added to the process's niceness. On a 2-core SBC the control loop and the camera must
    # get the CPU first; work that may lag (reconstruction drops frames by design, the
    # recorder and the viewer have queues) yields to them.
    nice: int = 0
    stop_grace_s: float = STOP_GRACE_S


def _camera_argv(args: argparse.Namespace) -> list[str]:
    argv = ["--source", args.source[0], "--rate", str(args.rate), "--seed", str(args.seed)]
    if len(args.source) > 1:
        argv += ["--socket" if args.source[0] == "sim-device" else "--file", args.source[1]]
    if args.source[0] == "sim":
        argv += sensor_argv(args)
    elif args.source[0] == "realsense":
        argv += realsense_argv(args)
    if not args.shed:
        argv.append("--no-shed")
    return argv


def _recorder_argv(args: argparse.Namespace) -> list[str]:
    return ["--out", args.record]


def _foxglove_argv(args: argparse.Namespace) -> list[str]:
    return ["--port", str(args.foxglove_port)]


def _emg_argv(args: argparse.Namespace) -> list[str]:
    """The EMG device flags (``_validate`` has checked they are there), or the scripted user."""
    match getattr(args, "emg", "sim"):
        case "serial":
            argv = ["--source", "serial", "--port", args.emg_port]
        case "can":
            argv = ["--source", "can", "--can", args.can_channel, "--interface", args.can_interface]
        case "lsl":
            argv = ["--source", "lsl", "--lsl-type", args.lsl_type or "EMG"]
            argv += ["--lsl-stream", args.lsl_stream] if args.lsl_stream else []
            argv += ["--lsl-scope", args.lsl_scope] if args.lsl_scope else []
        case "brainflow":
            argv = ["--source", "brainflow", "--board", args.board]
            argv += ["--serial-port", args.serial_port] if args.serial_port else []
            argv += ["--board-config", args.board_config] if args.board_config else []
        case _:
            return ["--source", "sim", "--seed", str(args.seed)]
    if getattr(args, "mains", None) is not None:
        argv += ["--mains", f"{args.mains:g}"]
    if getattr(args, "emg_channels", None) is not None:
        argv += ["--channels", *(str(c) for c in args.emg_channels)]
    return argv


def _channel_pair(text: str) -> tuple[int, int]:
    """``--emg-channels 0,1``: the source's flexor and extensor channel indices."""
    try:
        pair = tuple(int(part) for part in text.split(","))
    except ValueError:
        pair = ()
    if len(pair) != 2 or min(pair) < 0:
        raise argparse.ArgumentTypeError(f"want two channel indices like 0,1, not {text!r}")
    return pair  # type: ignore[return-value]


def _hand_argv(args: argparse.Namespace) -> list[str]:
    """The simulated CAN hand (or wrist), or the hand on ``--hand-can``'s bus, and the Ability
    Hand when asked for."""
    hand_can = getattr(args, "hand_can", None)
    if hand_can:
        interface, channel = hand_can.split(":", 1)
        argv = ["--interface", interface, "--channel", channel]
    else:
        argv = ["--sim-hand"]
    if getattr(args, "hand", "can") == "ability":
        argv += ["--hand", "ability"]
        if getattr(args, "hand_port", None):
            argv += ["--hand-port", args.hand_port]
    return argv


def _controller_argv(args: argparse.Namespace) -> list[str]:
    # The hand is always the simulated one (--sim-hand), and no camera turns with its wrist.
    # A real EMG needs the person's calibration; the scripted user has its own.
    user = ["--sim-user"] if _sim_user(args) else ["--profile", str(_profile_path(args))]
    return [*user, "--camera-fixed"]


def _profile_path(args: argparse.Namespace) -> Path:
    """The user profile: ``--profile``, else where ``lpc emg calibrate`` writes it."""
    from services.drivers.emg import DEFAULT_PROFILE

    return Path(getattr(args, "profile", None) or DEFAULT_PROFILE).expanduser()


# Start order: the recorder first (it must see everything), sources last. Stop order: reverse.
SERVICES: dict[str, ServiceSpec] = {
    "recorder": ServiceSpec(
        "services.recorder", _recorder_argv, lambda args: args.record is not None, nice=2
    ),
    "foxglove": ServiceSpec(
        "services.foxglove_bridge",
        _foxglove_argv,
        lambda args: getattr(args, "foxglove", False),
        nice=5,
    ),
    "scans": ServiceSpec("services.scans"),
    "reconstructor": ServiceSpec(
        "services.reconstructor",
        lambda args: ["--method", getattr(args, "method", "laser")],
        nice=5,
    ),
    # No --tactor-port: the bridge drives a simulated controller on a pseudo-terminal.
    "tactor_bridge": ServiceSpec(
        "services.tactor_bridge",
        lambda args: (
            ["--driver", args.tactor_driver]
            + (["--tactor-port", args.tactor_port] if args.tactor_port else [])
        ),
    ),
    # The simulated hand carries no camera: the tactor directions do not turn with its wrist.
    "aim": ServiceSpec("services.aim", lambda args: ["--camera-fixed"]),
    # The hand: python-can's virtual bus is in-process, so the bridge runs the simulated hand
    # (with --hand ability, the wrist rotator's CAN side of it), unless --hand-can names a bus.
    "prosthesis_bridge": ServiceSpec("services.prosthesis_bridge", lambda args: _hand_argv(args)),
    "controller": ServiceSpec("services.controller", _controller_argv),
    "emg": ServiceSpec("services.emg", _emg_argv),
    "camera": ServiceSpec("services.camera", _camera_argv),
}


# With --together these keep their own process: the hand's watchdog (40 ms) must outlive a
# crash of the process that runs the controller, or a real hand would keep its last velocity.
APART = ("prosthesis_bridge",)
CONTAINER = "container"
# With --together these run on the container's second event loop (its own thread): the
# control path at 100 Hz does not wait behind a frame's rendering or a chunk's compression.
CONTROL_LOOP = ("emg", "controller", "tactor_bridge")


def _container_child(args: argparse.Namespace, members: list[Child]) -> Child:
    """One child that runs ``members`` as tasks of one process (``services.container``)."""
    specs = [
        {"module": c.spec.module, "argv": ["--quiet", *c.argv]}
        | ({"loop": "control"} if c.name in CONTROL_LOOP else {})
        for c in members
    ]
    spec = ServiceSpec(
        "services.container",
        # The members stop in turn, each within the grace it has as a process of its own.
        stop_grace_s=STOP_GRACE_S * len(members),
    )
    child = Child(CONTAINER, spec, ["--services", json.dumps(specs)])
    child.members = {c.name: None for c in members}
    return child


def _sim_user(args: argparse.Namespace) -> bool:
    """The scripted EMG user unless an EMG device was asked for."""
    return getattr(args, "emg", "sim") == "sim"


@dataclass
class Child:
    name: str
    spec: ServiceSpec
    argv: list[str]
    process: asyncio.subprocess.Process | None = None
    restarts: int = 0
    next_start: float = 0.0
    alive: bool = False
    health: Health | None = None
    exit_codes: list[int] = field(default_factory=list)
    # The container's services (--together), with their latest health.
    members: dict[str, Health | None] = field(default_factory=dict)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--source",
        nargs="+",
        default=["sim"],
        metavar=("SOURCE", "FILE"),
        help="depth source: sim (built-in simulated scene, default), sim-device [SOCKET] (the "
        "same scene rendered by 'lpc sim-camera', read as a live camera), realsense [FILE.bag], "
        "or replay FILE.mcap",
    )
    parser.add_argument("--record", metavar="PATH", help="record every lpc/** topic to MCAP")
    parser.add_argument(
        "--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)"
    )
    parser.add_argument(
        "--services",
        nargs="+",
        metavar="NAME",
        help=f"services to start (default: all that apply): {', '.join(SERVICES)}",
    )
    parser.add_argument(
        "--port", type=int, default=7447, help="loopback port of the rendezvous (default 7447)"
    )
    parser.add_argument("--rate", type=float, default=90.0, help="camera frame rate (Hz)")
    parser.add_argument(
        "--no-shed",
        dest="shed",
        action="store_false",
        help="the camera publishes every frame even while the controller reports late ticks "
        "(default: it sheds frames first, so that the hand keeps its 100 Hz)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated scene")
    parser.add_argument(
        "--status-every",
        type=float,
        default=None,
        metavar="S",
        help="status period in seconds (default: live on a terminal, every 5 s otherwise)",
    )
    parser.add_argument(
        "--no-restart", action="store_true", help="do not restart a service that crashes"
    )
    parser.add_argument(
        "--tactor-port",
        metavar="PORT",
        help="serial port of the tactor controller (default: a simulated one on a pty)",
    )
    parser.add_argument(
        "--tactor-driver",
        choices=("eai", "line"),
        default="eai",
        help="tactor protocol: EAI controller framing (default) or the DIY line protocol",
    )
    parser.add_argument(
        "--hand",
        choices=("can", "ability"),
        default="can",
        help="the hand: lpc's CAN layout on a simulated hand (default), or a PSYONIC Ability "
        "Hand (--hand-port; simulated on a pty without one) in the grip chosen per object, "
        "its wrist rotator on CAN",
    )
    parser.add_argument(
        "--hand-port",
        metavar="PORT",
        help="serial port of the Ability Hand (--hand ability), e.g. /dev/ttyUSB0",
    )
    parser.add_argument(
        "--hand-can",
        metavar="INTERFACE:CHANNEL",
        help="the hand on this python-can bus instead of the simulated one in the bridge, e.g. "
        "serial:/dev/pts/3 (a simulated hand as a device: python -m services.hand_sim "
        "--ports-file)",
    )
    parser.add_argument(
        "--method",
        choices=("laser", "cloud"),
        default="laser",
        help="reconstruction: the four scan lines (default) or the full point cloud",
    )
    parser.add_argument(
        "--emg",
        choices=("sim", "serial", "can", "lsl", "brainflow"),
        default="sim",
        help="EMG source: a scripted simulated user (default), a serial amplifier (--emg-port), "
        "the hand's CAN status (--can-channel), a raw stream over the Lab Streaming Layer "
        "(--lsl-stream or --lsl-type) or a BrainFlow board (--board); a real EMG runs the "
        "controller on the calibrated --profile",
    )
    parser.add_argument(
        "--emg-channels",
        type=_channel_pair,
        metavar="F,E",
        help="the source's flexor and extensor channels (default 0,1)",
    )
    parser.add_argument(
        "--lsl-stream", metavar="NAME", help="LSL stream name (--emg lsl; default: by type)"
    )
    parser.add_argument("--lsl-type", metavar="TYPE", help="LSL stream type (--emg lsl; EMG)")
    parser.add_argument(
        "--lsl-scope",
        choices=("machine", "link", "site", "organization", "global"),
        help="LSL discovery scope (--emg lsl; machine: this computer only; default liblsl's "
        "configuration, lsl_api.cfg)",
    )
    parser.add_argument(
        "--board",
        metavar="NAME",
        help="BrainFlow board (--emg brainflow): cyton, ganglion, cyton_daisy, synthetic, ... "
        "any name or id BrainFlow knows",
    )
    parser.add_argument(
        "--serial-port", metavar="PORT", help="serial port of the BrainFlow board (e.g. cyton)"
    )
    parser.add_argument(
        "--board-config",
        metavar="CMD",
        help="settings command for the BrainFlow board (BrainFlow's config_board), sent "
        "before it streams; e.g. a Cyton's channel settings",
    )
    parser.add_argument(
        "--mains",
        type=int,
        choices=(50, 60),
        help="mains frequency notched out of raw EMG, Hz (--emg lsl|brainflow; default 50)",
    )
    parser.add_argument(
        "--emg-port", metavar="PORT", help="serial port of the EMG amplifier (--emg serial)"
    )
    parser.add_argument(
        "--can-channel", metavar="CHANNEL", help="CAN channel carrying the EMG (--emg can)"
    )
    parser.add_argument(
        "--can-interface",
        default="socketcan",
        metavar="NAME",
        help="python-can interface of --can-channel (default socketcan)",
    )
    parser.add_argument(
        "--profile",
        metavar="FILE",
        help="user profile with the EMG calibration (--emg serial|can; default the one "
        "'lpc emg calibrate' writes, ~/.config/lpc/profile.json)",
    )
    parser.add_argument(
        "--foxglove",
        action="store_true",
        help="also serve everything to Foxglove (WebSocket on 127.0.0.1; needs lpc[foxglove])",
    )
    parser.add_argument(
        "--foxglove-port", type=int, default=8765, help="Foxglove WebSocket port (default 8765)"
    )
    parser.add_argument(
        "--together",
        action="store_true",
        help="run the services as tasks of one process on one Zenoh session (for small "
        f"boards; same topics); {', '.join(APART)} keeps its own process for the hand's "
        "watchdog, the reconstructor its worker processes",
    )
    add_sensor_arguments(parser)
    add_realsense_arguments(parser)


def _validate(args: argparse.Namespace) -> str | None:
    kind = args.source[0]
    if kind not in ("sim", "sim-device", "realsense", "replay"):
        return f"--source must be sim, sim-device, realsense or replay, not {kind!r}"
    if kind == "replay" and len(args.source) != 2:
        return "--source replay needs the recording: --source replay FILE.mcap"
    if kind == "sim" and len(args.source) != 1:
        return "--source sim takes no file"
    if len(args.source) > 2:
        return "--source takes at most a kind and a file"
    if args.duration is not None and not args.duration > 0:  # also rejects nan
        return "--duration must be positive"
    if not 0 < args.rate <= 1000:
        return "--rate must be in (0, 1000] Hz"
    if not 1 <= args.port <= 65535:
        return "--port must be a TCP port number"
    if not 0 <= getattr(args, "foxglove_port", 8765) <= 65535:
        return "--foxglove-port must be a TCP port number"
    if getattr(args, "hand_port", None) and getattr(args, "hand", "can") != "ability":
        return "--hand-port is for --hand ability"
    if getattr(args, "hand_can", None) and ":" not in args.hand_can:
        return "--hand-can wants INTERFACE:CHANNEL, e.g. serial:/dev/pts/3"
    if getattr(args, "hand_can", None) and getattr(args, "hand", "can") != "can":
        return "--hand-can is for --hand can"
    try:
        stereo_sensor(args)
    except ValueError as exc:
        return str(exc)
    if not 1e-6 <= getattr(args, "rs_depth_units", 0.001) <= 0.01:
        return "--rs-depth-units must be in [1e-6, 0.01] m"
    unknown = sorted(set(args.services or []) - set(SERVICES))
    if unknown:
        return f"unknown service(s) {', '.join(unknown)}; known: {', '.join(SERVICES)}"
    return _validate_emg(args)


def _validate_emg(args: argparse.Namespace) -> str | None:
    """Each EMG source has its device flags and no other's; a real EMG, a calibration."""
    emg = getattr(args, "emg", "sim")
    given = {
        flag: getattr(args, flag.removeprefix("--").replace("-", "_"), None) is not None
        for flag in (
            "--emg-port",
            "--can-channel",
            "--profile",
            "--emg-channels",
            "--lsl-stream",
            "--lsl-type",
            "--lsl-scope",
            "--board",
            "--serial-port",
            "--board-config",
            "--mains",
        )
    }
    needs = {
        "sim": (),
        "serial": ("--emg-port",),
        "can": ("--can-channel",),
        "lsl": (),
        "brainflow": ("--board",),
    }[emg]
    examples = {"--emg-port": "/dev/ttyUSB0", "--can-channel": "can0", "--board": "cyton"}
    for flag in needs:
        if not given[flag]:
            return f"--emg {emg} needs {flag} (e.g. {flag} {examples[flag]})"
    if emg == "lsl" and given["--lsl-stream"] and given["--lsl-type"]:
        return "--lsl-stream and --lsl-type are alternatives: give one"
    optional = {
        "lsl": ("--lsl-stream", "--lsl-type", "--lsl-scope", "--mains"),
        "brainflow": ("--serial-port", "--board-config", "--mains"),
    }.get(emg, ())
    allowed = {*needs, *optional, "--profile", "--emg-channels"} if emg != "sim" else set()
    for flag, present in given.items():
        if present and flag not in allowed:
            if flag == "--profile":
                return (
                    "--profile is for a real EMG (--emg serial|can|lsl|brainflow); the simulated "
                    "user has its own calibration"
                )
            return f"{flag} does not apply to --emg {emg}"
    if emg == "sim" or "controller" not in (args.services or SERVICES):
        return None
    from services.drivers.emg import load_emg_profile

    path = _profile_path(args)
    calibrate = f"run 'lpc emg calibrate --source {emg} ...' first, or give --profile FILE"
    if not path.exists():
        return f"--emg {emg} needs the user's EMG calibration; {path} does not exist: {calibrate}"
    try:
        profile = load_emg_profile(path)
    except ValueError as exc:
        return str(exc)
    if profile is None:
        return f"no EMG calibration (emg section) in {path}: {calibrate}"
    return None


def run(args: argparse.Namespace) -> int:
    problem = _validate(args)
    if problem:
        print(f"lpc up: error: {problem}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_supervise(args))
    except KeyboardInterrupt:
        return 130


async def _supervise(args: argparse.Namespace) -> int:
    endpoint = f"tcp/127.0.0.1:{args.port}"
    wanted = args.services or list(SERVICES)
    children = [
        Child(name, spec, spec.argv(args))
        for name, spec in SERVICES.items()
        if name in wanted and spec.enabled(args)
    ]
    if getattr(args, "together", False):
        members = [c for c in children if c.name not in APART]
        apart = [c for c in children if c.name in APART]
        children = ([_container_child(args, members)] if members else []) + apart
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        session = zenoh.open(zenoh_config(connect=[], listen=[endpoint]))
    except zenoh.ZError as exc:
        print(
            f"lpc up: error: cannot listen on {endpoint} ({exc}); is another 'lpc up' running? "
            "Choose another --port.",
            file=sys.stderr,
        )
        return 2
    by_name = {c.name: c for c in children}
    with session:

        def on_health(sample: zenoh.Sample) -> None:
            payload = sample.payload.to_bytes()
            key = str(sample.key_expr)
            loop.call_soon_threadsafe(_store_health, by_name, key, payload)

        def on_alive(sample: zenoh.Sample) -> None:
            name = str(sample.key_expr).rsplit("/", 1)[-1]
            up = sample.kind == zenoh.SampleKind.PUT
            loop.call_soon_threadsafe(_set_alive, by_name, name, up)

        health_sub = session.declare_subscriber("lpc/health/*", on_health)
        alive_sub = session.liveliness().declare_subscriber("lpc/alive/*", on_alive, history=True)
        try:
            code = await _run_children(args, endpoint, children, stop)
        finally:
            await _stop_all(children)
            health_sub.undeclare()
            alive_sub.undeclare()
    _print_summary(children)
    if code == 0 and any(_unclean(c) for c in children):
        code = 1
    return code


def _store_health(by_name: dict[str, Child], key: str, payload: bytes) -> None:
    try:
        health = decode(key, payload)
    except (ValueError, KeyError):
        return
    child = by_name.get(health.service)
    container = by_name.get(CONTAINER)
    if child is None and container is not None and health.service in container.members:
        container.members[health.service] = health
        return
    if child is not None:
        child.health = health
        # Health proves the service is up even when its liveliness token is slow to arrive.
        if health.status != "stopping" and child.process is not None:
            child.alive = True


def _set_alive(by_name: dict[str, Child], name: str, up: bool) -> None:
    child = by_name.get(name)
    if child is not None:
        child.alive = up


async def _spawn(child: Child, endpoint: str) -> None:
    child.process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        child.spec.module,
        "--connect",
        endpoint,
        "--quiet",
        *child.argv,
        stdin=asyncio.subprocess.DEVNULL,
        preexec_fn=lambda: _prepare_child(child.spec.nice),
    )


def _prepare_child(nice: int) -> None:
    """In the child before exec: get SIGTERM if the supervisor dies, so no service is orphaned,
    and take the service's niceness."""
    die_with_parent()
    if nice:
        with contextlib.suppress(OSError):
            os.nice(nice)


async def _run_children(
    args: argparse.Namespace, endpoint: str, children: list[Child], stop: asyncio.Event
) -> int:
    for child in children:
        await _spawn(child, endpoint)
    # The duration counts from the moment every service holds its liveliness token.
    deadline = time.monotonic() + START_TIMEOUT_S
    while not all(c.alive for c in children):
        if stop.is_set():
            return 130
        failed = [c for c in children if c.process and c.process.returncode is not None]
        if failed or time.monotonic() > deadline:
            names = ", ".join(c.name for c in failed or children if not c.alive)
            print(f"lpc up: error: service(s) failed to start: {names}", file=sys.stderr)
            return 1
        await asyncio.sleep(0.05)
    started = time.monotonic()
    print(
        f"lpc up: {len(children)} services up on {endpoint}: "
        + ", ".join(c.name for c in children),
        file=sys.stderr,
        flush=True,
    )
    live = sys.stdout.isatty() and args.status_every is None
    every = args.status_every or (1.0 if live else 5.0)
    next_status = started + every
    while not stop.is_set():
        now = time.monotonic()
        if args.duration is not None and now - started >= args.duration:
            break
        for child in children:
            await _check_child(child, endpoint, no_restart=args.no_restart)
        if now >= next_status:
            _print_status(children, now - started, live)
            next_status += every
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(0.1):
                await stop.wait()
    return 0


async def _check_child(child: Child, endpoint: str, *, no_restart: bool) -> None:
    process = child.process
    if process is None:
        if time.monotonic() >= child.next_start:
            print(f"lpc up: restarting {child.name} (restart #{child.restarts})", file=sys.stderr)
            await _spawn(child, endpoint)
        return
    if process.returncode is None:
        return
    child.exit_codes.append(process.returncode)
    child.process = None
    child.alive = False
    if no_restart:
        print(f"lpc up: {child.name} exited with {process.returncode}", file=sys.stderr)
        child.next_start = float("inf")
        return
    child.restarts += 1
    backoff = min(0.25 * 2 ** (child.restarts - 1), 5.0)
    child.next_start = time.monotonic() + backoff
    print(
        f"lpc up: {child.name} exited with {process.returncode}; restart in {backoff:.2f} s",
        file=sys.stderr,
        flush=True,
    )


async def _stop_all(children: list[Child]) -> None:
    """SIGTERM in reverse start order, each given the grace period, then SIGKILL."""
    for child in reversed(children):
        process = child.process
        if process is None or process.returncode is not None:
            continue
        with contextlib.suppress(ProcessLookupError):
            process.send_signal(signal.SIGTERM)
        try:
            async with asyncio.timeout(child.spec.stop_grace_s):
                await process.wait()
        except TimeoutError:
            print(
                f"lpc up: {child.name} did not stop in {child.spec.stop_grace_s} s; killing it",
                file=sys.stderr,
            )
            with contextlib.suppress(ProcessLookupError):
                process.kill()
            await process.wait()
        child.exit_codes.append(process.returncode if process.returncode is not None else -9)


def _unclean(child: Child) -> bool:
    return bool(child.exit_codes) and child.exit_codes[-1] != 0


def _status_line(child: Child) -> str:
    return _health_line(child.name, child.health, child.alive, child.restarts)


def _health_line(name: str, h: Health | None, alive: bool, restarts: int) -> str:
    if h is None:
        return f"{name:<18} {'up' if alive else 'down':<8} (no health yet)"
    rate = ", ".join(f"{k.removeprefix('lpc/')} {v:5.1f} Hz" for k, v in h.rates_hz.items())
    lat = h.latency_ms
    latency = f"lat p50 {lat['p50']:6.2f} ms p99 {lat['p99']:6.2f} ms" if lat else "lat -"
    c = h.counters
    restarts += c.get("restarts", 0) if name != CONTAINER else 0
    return (
        f"{name:<18} {h.status:<8} {rate or '-':<28} {latency}  "
        f"in {c.get('received', 0)} drop {c.get('dropped', 0)} rej {c.get('rejected', 0)}  "
        f"rss {h.rss_bytes / 2**20:5.0f} MB" + (f"  restarts {restarts}" if restarts else "")
    )


def _print_status(children: list[Child], elapsed: float, live: bool) -> None:
    lines = [f"--- t = {elapsed:6.1f} s"]
    for child in children:
        lines.append(_status_line(child))
        lines += [_health_line(f"  {name}", h, child.alive, 0) for name, h in child.members.items()]
    if live:
        sys.stdout.write(
            f"\x1b[{len(lines)}F\x1b[J" if getattr(_print_status, "drawn", False) else ""
        )
        _print_status.drawn = True  # type: ignore[attr-defined]
    sys.stdout.write("\n".join(lines) + "\n")
    sys.stdout.flush()


def _print_summary(children: list[Child]) -> None:
    summary = {
        c.name: {
            "exit": c.exit_codes[-1] if c.exit_codes else None,
            "restarts": c.restarts,
            "rates_hz": c.health.rates_hz if c.health else {},
            "latency_ms": c.health.latency_ms if c.health else {},
            "counters": c.health.counters if c.health else {},
        }
        for c in children
    }
    for c in children:  # a container's services, as if they were children
        for name, h in c.members.items():
            summary[name] = {
                "exit": summary[c.name]["exit"],
                "restarts": c.restarts + (h.counters.get("restarts", 0) if h else 0),
                "rates_hz": h.rates_hz if h else {},
                "latency_ms": h.latency_ms if h else {},
                "counters": h.counters if h else {},
            }
    print("lpc up: summary " + json.dumps(summary, sort_keys=True), file=sys.stderr, flush=True)
