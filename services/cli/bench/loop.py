"""``lpc bench loop``: the closed loop's figures from a recording (or a fresh ``lpc up`` run).

Reads ``lpc/controller/state``, ``lpc/emg``, ``lpc/prosthesis/command`` and
``lpc/prosthesis/state`` and prints: the states visited and each transition's count, the
pre-shapes (time to reach the target, and the error when the controller reported it against
the hand's own status), the same per grip (``lpc_core.perception.grip``; a one-grip hand makes
every pre-shape in power), the rates of the three 100 Hz topics, the gaps in the command stream,
and the targets of issue 7 (all four states visited, a pre-shape within tolerance, >= 95 Hz).
With ``--run S`` it first records ``lpc up --source sim --duration S`` (``--hand ability``:
with the simulated Ability Hand).

``--grips`` measures every grip of the Ability Hand without the scene (which shows only the
grips its objects call for): the controller's step function, in this process, pre-shapes the
real driver and the simulated hand over a pty (wrist on python-can's virtual bus) for one
object per grip, ``--repeat`` times, in real time.
"""

from __future__ import annotations

import argparse
import bisect
import json
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from lpc_core.control.controller import ControllerParams
from services.mcap_log import read_messages

RATE_TOPICS = ("lpc/emg", "lpc/prosthesis/command", "lpc/prosthesis/state")
REQUIRED_STATES = ("aiming", "ready", "preshaping", "direct")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", nargs="?", help="an MCAP recording of a session")
    parser.add_argument("--run", type=float, metavar="S", help="record a sim session of S s first")
    parser.add_argument("--port", type=int, default=7447, help="rendezvous port for --run")
    parser.add_argument(
        "--hand",
        choices=("can", "ability"),
        default="can",
        help="the hand of the --run session: lpc's CAN hand (default) or the Ability Hand",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object instead of text")
    parser.add_argument(
        "--grips",
        action="store_true",
        help="pre-shape the simulated Ability Hand once per grip (no scene, no bus)",
    )
    parser.add_argument("--repeat", type=int, default=3, help="pre-shapes per grip (--grips)")


def run(args: argparse.Namespace) -> int:
    if args.grips:
        if not 1 <= args.repeat <= 50:
            print("lpc bench loop: error: --repeat must be 1..50", file=sys.stderr)
            return 2
        figures = preshape_per_grip(args.repeat)
        print(json.dumps(figures, sort_keys=True) if args.json else _grip_lines(figures))
        return 0 if all(g["reached"] == g["preshapes"] for g in figures.values()) else 1
    path = args.recording
    if args.run is not None:
        if not 5 <= args.run <= 3600:
            print("lpc bench loop: error: --run must be 5..3600 s", file=sys.stderr)
            return 2
        path = path or str(Path(tempfile.mkdtemp(prefix="lpc-loop-")) / "session.mcap")
        cmd = [
            sys.executable,
            "-m",
            "services.cli",
            "up",
            "--source",
            "sim",
            "--duration",
            str(args.run),
            "--record",
            path,
            "--port",
            str(args.port),
            "--status-every",
            "1e9",
            "--hand",
            args.hand,
        ]
        code = subprocess.call(cmd, stdout=subprocess.DEVNULL)
        if code != 0:
            print(f"lpc bench loop: error: lpc up exited with {code}", file=sys.stderr)
            return 1
    if not path or not Path(path).is_file():
        print("lpc bench loop: error: give a recording or --run S", file=sys.stderr)
        return 2
    figures = analyse(path)
    if args.json:
        print(json.dumps(figures, sort_keys=True))
    else:
        _print(figures)
    return 0 if figures["targets_met"] else 1


def analyse(path: str) -> dict:
    keys = ("lpc/controller/state", *RATE_TOPICS)
    messages: dict[str, list] = {k: [] for k in keys}
    log_times: dict[str, list[int]] = {k: [] for k in keys}
    for m in read_messages(path, keys):
        if m.message is not None:
            messages[m.key].append(m.message)
            log_times[m.key].append(m.log_time)
    states = messages["lpc/controller/state"]
    transitions = [s for s in states if s.event and s.previous != s.state]
    visited = sorted({s.state for s in transitions})
    counts = Counter(f"{s.previous} -> {s.state} ({s.event})" for s in transitions)

    p = ControllerParams()
    hands = messages["lpc/prosthesis/state"]
    hand_t = [h.t_ns for h in hands]
    preshapes = []
    for i, s in enumerate(states):
        if not (s.event == "auto_preshape" and s.state == "preshaping"):
            continue
        reached = next((r for r in states[i:] if r.event == "at_target"), None)
        left = next((r for r in states[i + 1 :] if r.state != "preshaping"), None)
        entry: dict = {
            "t_s": round((s.t_ns - states[0].t_ns) / 1e9, 2),
            "reached": False,
            "grip": s.grip,
        }
        if reached is not None and (left is None or reached.t_ns <= left.t_ns):
            k = bisect.bisect_left(hand_t, reached.t_ns)
            hand = hands[min(k, len(hands) - 1)]
            target_ap = min((s.target_width_mm or 0.0) + p.slack_mm, 110.0)
            ap_err = hand.aperture_mm - target_ap
            wr_err = (
                0.0
                if reached.target_angle_deg is None
                else hand.wrist_angle_deg - reached.target_angle_deg
            )
            entry.update(
                reached=abs(ap_err) <= p.aperture_tol_mm + 0.5
                and abs(wr_err) <= p.wrist_tol_deg + 0.5,
                time_to_target_ms=round((reached.t_ns - s.t_ns) / 1e6, 1),
                aperture_error_mm=round(ap_err, 2),
                wrist_error_deg=round(wr_err, 2),
            )
        preshapes.append(entry)

    rates = {}
    for key in RATE_TOPICS:
        t = np.asarray(log_times[key], dtype=np.int64)
        rates[key] = round((len(t) - 1) / ((t[-1] - t[0]) / 1e9), 2) if len(t) > 1 else 0.0
    cmd_t = np.asarray(log_times["lpc/prosthesis/command"], dtype=np.int64)
    gaps = np.diff(cmd_t) / 1e6 if len(cmd_t) > 1 else np.zeros(1)
    figures = {
        "recording": str(path),
        "visited": visited,
        "transitions": dict(counts),
        "preshapes": preshapes,
        "rates_hz": rates,
        "command_gap_ms": {
            "p50": round(float(np.percentile(gaps, 50)), 2),
            "p99": round(float(np.percentile(gaps, 99)), 2),
            "max": round(float(gaps.max()), 2),
            "over_50ms": int((gaps > 50).sum()),
        },
    }
    figures["hand"] = hands[-1].hand if hands else ""
    figures["per_grip"] = _per_grip(preshapes)
    figures["targets"] = {
        "states_visited": all(s in visited for s in REQUIRED_STATES),
        "preshape_within_tolerance": any(e["reached"] for e in preshapes),
        "rates_at_least_95_hz": all(r >= 95.0 for r in rates.values()),
    }
    figures["targets_met"] = all(figures["targets"].values())
    return figures


def _per_grip(preshapes: list[dict]) -> dict:
    """Per grip: pre-shapes, how many reached the target, median time to it, mean |error|."""
    out = {}
    for grip in sorted({e["grip"] for e in preshapes}):
        mine = [e for e in preshapes if e["grip"] == grip]
        timed = [e for e in mine if "time_to_target_ms" in e]
        out[grip] = {
            "preshapes": len(mine),
            "reached": sum(e["reached"] for e in mine),
            "time_to_target_ms_p50": (
                round(float(np.median([e["time_to_target_ms"] for e in timed])), 1)
                if timed
                else None
            ),
            "aperture_error_mm_mean_abs": (
                round(float(np.mean([abs(e["aperture_error_mm"]) for e in timed])), 2)
                if timed
                else None
            ),
        }
    return out


def _print(f: dict) -> None:
    print(f"recording      {f['recording']}")
    print(f"hand           {f['hand']}")
    print(f"visited        {', '.join(f['visited'])}")
    for name, count in sorted(f["transitions"].items()):
        print(f"  {count:4d}  {name}")
    for e in f["preshapes"]:
        if e["reached"] or "time_to_target_ms" in e:
            print(
                f"pre-shape at {e['t_s']:7.2f} s ({e['grip']:<7}): target in "
                f"{e['time_to_target_ms']:6.1f} ms, aperture error {e['aperture_error_mm']:+.2f} "
                f"mm, wrist error {e['wrist_error_deg']:+.2f} deg"
            )
        else:
            print(f"pre-shape at {e['t_s']:7.2f} s ({e['grip']:<7}): left before the target")
    for grip, g in f["per_grip"].items():
        t = g["time_to_target_ms_p50"]
        err = g["aperture_error_mm_mean_abs"]
        print(
            f"grip {grip:<9} {g['preshapes']} pre-shapes, {g['reached']} reached; time to "
            f"target p50 {'-' if t is None else f'{t:.0f} ms'}, aperture |error| mean "
            f"{'-' if err is None else f'{err:.2f} mm'}"
        )
    for key, rate in f["rates_hz"].items():
        print(f"rate           {key:<24} {rate:7.2f} Hz")
    g = f["command_gap_ms"]
    print(
        f"command gaps   p50 {g['p50']} ms  p99 {g['p99']} ms  max {g['max']} ms  "
        f"> 50 ms: {g['over_50ms']}"
    )
    for name, ok in f["targets"].items():
        print(f"target         {name:<28} {'met' if ok else 'NOT MET'}")


# One object per grip, as the rule table chooses for it: (shape, width mm, axis angle deg).
GRIP_OBJECTS = {
    "power": ("cylinder", 70.0, 20.0),
    "tripod": ("sphere", 40.0, None),
    "lateral": ("cuboid", 30.0, 20.0),
    "pinch": ("cylinder", 12.0, 20.0),
}


def preshape_per_grip(repeat: int, timeout_s: float = 5.0) -> dict:
    """Per grip: time from the trigger to the controller's ``at_target`` and the aperture
    error then, with the real Ability Hand driver on a simulated hand over a pty."""
    import itertools
    import time

    from lpc_core.control.controller import (
        ControllerCore,
        Event,
        State,
        Tick,
        apply_event,
        controller_step,
    )
    from lpc_core.devices.hand import HandCommand
    from lpc_core.perception.grip import choose_grip
    from schemas import EmgSample, ProsthesisCommand, ProsthesisState
    from services.drivers.ability import open_ability
    from services.drivers.ability_sim import AbilitySim
    from services.drivers.hand_sim import SimulatedHand

    figures: dict = {}
    seq = itertools.count(1)
    for grip, (shape, width, angle) in GRIP_OBJECTS.items():
        choice = choose_grip(shape, width, angle)
        assert choice.grip == grip, (grip, choice)
        times, errors, retriggers = [], [], 0
        for k in range(repeat):
            channel = f"lpc-bench-grip-{grip}-{k}-{time.monotonic_ns()}"
            with (
                AbilitySim() as fingers,
                SimulatedHand("lpc", channel=channel),
                open_ability(fingers.port, channel=channel) as hand,
            ):
                core, command = ControllerCore(), HandCommand()
                start = reached = None
                deadline = time.monotonic() + timeout_s
                while reached is None and time.monotonic() < deadline:
                    status = hand.recv(0.02)
                    now = time.time_ns()
                    n = next(seq)
                    inputs: list = [EmgSample(seq=n, t_ns=now, channels=[0.0, 0.0]), Tick(now)]
                    if status is not None:
                        inputs.insert(
                            0,
                            ProsthesisState(
                                seq=n,
                                t_ns=now,
                                wrist_angle_deg=status.wrist_angle_deg,
                                aperture_mm=status.aperture_mm,
                                grip_force_pct=status.grip_force_pct,
                                grip=status.grip,  # type: ignore[arg-type]
                            ),
                        )
                    # Vision keeps reporting the object (the target goes stale without it).
                    inputs.append(_target(n, now, shape, width, angle, grip))
                    out: list = []
                    for message in inputs:
                        core, produced = controller_step(core, message, now)
                        out += produced
                    if core.mode is State.READY and core.hand is not None:
                        # The trigger; again after a stall of this process stopped the
                        # controller (the time counts from the first).
                        core = apply_event(core, Event.AUTO_PRESHAPE, now, "bench", out)
                        retriggers += start is not None
                        start = start if start is not None else time.monotonic()
                    for o in out:
                        if isinstance(o, ProsthesisCommand):
                            command = HandCommand(grasp=o.grasp, wrist=o.wrist, grip=o.grip)
                        elif getattr(o, "event", "") == "at_target" and start is not None:
                            reached = time.monotonic() - start
                    hand.send(command)
                if reached is not None and core.setpoint is not None and core.hand is not None:
                    times.append(1000.0 * reached)
                    errors.append(core.hand.aperture_mm - core.setpoint.aperture_mm)
        figures[grip] = {
            "object": f"{shape} {width:g} mm",
            "preshapes": repeat,
            "reached": len(times),
            "time_to_target_ms_p50": round(float(np.median(times)), 1) if times else None,
            "time_to_target_ms_max": round(float(np.max(times)), 1) if times else None,
            "aperture_error_mm_mean_abs": (
                round(float(np.mean(np.abs(errors))), 2) if errors else None
            ),
            "retriggers": retriggers,
        }
    return figures


def _target(n: int, t_ns: int, shape: str, width: float, angle: float | None, grip: str):  # type: ignore[no-untyped-def]
    from schemas import GraspTarget

    return GraspTarget(
        seq=n,
        t_ns=t_ns,
        frame_seq=n,
        shape=shape,  # type: ignore[arg-type]
        grasp_width_mm=width,
        wrist_angle_deg=angle,
        reconstructed=True,
        frames=10,
        agreement=1.0,
        grip=grip,  # type: ignore[arg-type]
    )


def _grip_lines(figures: dict) -> str:
    lines = []
    for grip, g in figures.items():
        t, tmax, err = (
            g["time_to_target_ms_p50"],
            g["time_to_target_ms_max"],
            g["aperture_error_mm_mean_abs"],
        )
        lines.append(
            f"grip {grip:<8} {g['object']:<16} {g['reached']}/{g['preshapes']} reached; time to "
            f"target p50 {'-' if t is None else f'{t:.0f} ms'} (max "
            f"{'-' if tmax is None else f'{tmax:.0f} ms'}), aperture |error| mean "
            f"{'-' if err is None else f'{err:.2f} mm'}"
            + (f"; {g['retriggers']} re-triggered after a stall" if g["retriggers"] else "")
        )
    return "\n".join(lines)
