"""Aim guidance: ``lpc/scans``, ``lpc/grasp/target``, ``lpc/controller/state`` and
``lpc/prosthesis/state`` in; ``lpc/tactors/command`` and ``lpc/aim/cue`` out, one of each per
frame (all off while the controller has stopped the hand). With the camera on the hand (the
default), the tactor directions turn with the hand's reported wrist angle."""

from __future__ import annotations

import argparse
import sys

from lpc_core.control.aim import AimParams, AimState, aim_step, tactor_placement
from schemas import AimCue, TactorCommand
from services.drivers.tactors import load_profile
from services.runtime import Bus, service_main, service_parser


def params_from(args: argparse.Namespace) -> AimParams:
    """Flags win over the user profile's ``tactors`` section, which wins over the defaults."""
    section = load_profile(args.profile)
    arm = args.arm or section.get("arm", "right")
    rotation = args.rotation_deg if args.rotation_deg is not None else section.get("rotation_deg")
    return AimParams(
        tactor_angles_rad=tactor_placement(arm, float(rotation or 0.0)),
        cluster_gap_m=args.gap_mm / 1000.0,
        hysteresis_m=args.hysteresis_mm / 1000.0,
        follow_wrist=not args.camera_fixed,
    )


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    state = initial_state(args)
    commands = bus.publisher("lpc/tactors/command")
    cues = bus.publisher("lpc/aim/cue")

    # These only update the state that frames are read against: the newest of each is taken
    # when a frame arrives, so that no sample of theirs wakes the loop or a task (the hand's
    # status alone is 100 a second).
    keys = ["lpc/grasp/target", "lpc/controller/state"]
    if state.params.follow_wrist:
        keys.append("lpc/prosthesis/state")
    followed = [bus.newest(key) for key in keys]
    async for scans in bus.subscribe("lpc/scans"):
        for newest in followed:
            message = newest.take()
            if message is not None:
                state, _ = aim_step(state, message, bus.clock.now_ns())
        try:
            state, outputs = aim_step(state, scans, bus.clock.now_ns())
        except ValueError as exc:
            bus.reject("lpc/scans", str(exc))
            continue
        # The tactor command first: it is the one on the latency path.
        for out in outputs:
            if isinstance(out, TactorCommand):
                commands.put(out)
        for out in outputs:
            if isinstance(out, AimCue):
                cues.put(out)


def parser() -> argparse.ArgumentParser:
    """The service's flags (a replay parses the recorded ones with it)."""
    parser = service_parser("aim", __doc__ or "")
    parser.add_argument("--profile", metavar="FILE", help="user profile JSON (tactor placement)")
    parser.add_argument("--arm", choices=("left", "right"), help="arm wearing the tactors")
    parser.add_argument("--rotation-deg", type=float, help="rotation of the tactor sleeve (deg)")
    parser.add_argument(
        "--gap-mm", type=float, default=10.0, help="gap that separates two objects (mm)"
    )
    parser.add_argument(
        "--hysteresis-mm", type=float, default=2.0, help="on-target hysteresis band (mm)"
    )
    parser.add_argument(
        "--camera-fixed",
        action="store_true",
        help="the camera does not turn with the wrist: tactor directions ignore the wrist angle",
    )
    return parser


def initial_state(args: argparse.Namespace) -> AimState:
    """The step function's state at start, from the flags; ``ValueError`` if they are bad."""
    return AimState(params=params_from(args))


def main(argv: list[str] | None = None) -> int:
    return service_main("aim", parser(), initial_state, serve, argv)


if __name__ == "__main__":
    sys.exit(main())
