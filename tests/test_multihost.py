"""lpc across hosts: a wearable, a laptop and an intruder in network namespaces (tests/netns.py),
with the shipped secure Zenoh configs (mutual TLS, access control) and a throw-away CA.

The wearable runs a router and everything the hand needs; the laptop runs a router joined to
the wearable's, the recorder and the Foxglove bridge. One deployment serves the whole module,
in order: intruders, a steady recording, a cut cable, then the reconstructor moved to the
laptop and the cable cut again. Each scenario prints its figures (pytest -s, or the summary at
the end of the run). Needs root; skipped with the reason otherwise.

``LPC_MULTIHOST_SECONDS`` sets the steady recording's length (default 15 s; the issue's 30 s
fits in CI's 2 minutes only on an idle machine).
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import os
import re
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from services.cli import main as lpc
from services.cli.certs import ROLES, make_certs
from services.mcap_log import McapLog, McapLogError
from tests import netns

STEADY_S = float(os.environ.get("LPC_MULTIHOST_SECONDS", "15"))
CUT_S = 3.0
STALE_TARGET_MS = 1000.0  # the controller's default --stale-target-ms
W, L = netns.ADDRESSES["wearable"], netns.ADDRESSES["laptop"]
LOCAL = "tls/127.0.0.1:7447"  # every service dials its own host's router
REPORT: list[str] = []

WEARABLE = {
    "camera": ["--source", "sim", "--rate", "90", "--seed", "0"],
    "scans": [],
    "reconstructor": [],
    "aim": ["--camera-fixed"],
    "emg": ["--source", "sim", "--seed", "0"],
    "controller": ["--sim-user", "--camera-fixed"],
    "prosthesis_bridge": ["--sim-hand"],
    "tactor_bridge": [],
}


@dataclass
class Probe:
    """What a subscriber on one host saw: one dict per sample (key, seq, times, fields)."""

    samples: list[dict] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __call__(self, line: str) -> None:
        try:
            sample = json.loads(line)
        except json.JSONDecodeError:
            return
        with self.lock:
            self.samples.append(sample)

    def of(self, key: str, after_ns: int = 0) -> list[dict]:
        with self.lock:
            return [s for s in self.samples if s.get("k") == key and s["r"] >= after_ns]

    def keys(self, t0: int, t1: int) -> dict[str, set[int]]:
        seen: dict[str, set[int]] = defaultdict(set)
        with self.lock:
            for s in self.samples:
                if "s" in s and t0 <= s["t"] <= t1:
                    seen[s["k"]].add(s["s"])
        return seen


@dataclass
class Deployment:
    hosts: netns.Hosts
    work: Path
    certs: Path
    other_ca: Path
    recording: Path
    probe: Probe
    services: dict[str, subprocess.Popen[str]]
    stopped: set[str] = field(default_factory=set)
    router_lines: dict[str, list[str]] = field(default_factory=dict)

    def client_config(self, role: str, *, name: str = "", connect: str = LOCAL) -> Path:
        return netns.config(
            netns.SERVICE_CONF, self.certs, role, self.work, connect=[connect], name=name
        )

    def start_service(self, host: str, module: str, role: str, argv: list[str]) -> None:
        config = self.client_config(role, name=f"{host}-{role}")
        self.services[f"{host}/{module}"] = self.hosts.start(
            host, ["-m", f"services.{module}", "--config", str(config), "--quiet", *argv],
            name=module,
        )  # fmt: skip

    def recorded(self) -> list:
        """The recording so far: a file being written reads up to its last finished chunk."""
        try:
            with McapLog(self.recording) as log:
                return list(log.messages(ordered=False))
        except McapLogError:
            return []

    def controller_states(self, after_ns: int) -> list[dict]:
        return self.probe.of("lpc/controller/state", after_ns)


def report(*lines: str) -> None:
    REPORT.extend(lines)
    print("\n".join(lines))


@pytest.fixture(scope="module")
def deployment(
    tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> Iterator[Deployment]:
    reason = netns.unavailable()
    if reason:
        pytest.skip(reason)
    started = time.monotonic()
    stale = netns.remove_stale()
    work = tmp_path_factory.mktemp("multihost")
    certs, other_ca = work / "certs", work / "other-ca"
    make_certs(certs, roles=[*ROLES, "stranger"], router_names=[W, L], days=2)
    make_certs(other_ca, roles=["controller"], router_names=[W, L], days=2)
    hosts = netns.Hosts(work)

    def finish() -> None:
        hosts.close()
        left = hosts.remaining()
        terminal = request.config.pluginmanager.get_plugin("terminalreporter")
        lines = [
            "",
            "multi-host harness",
            *REPORT,
            f"namespaces left after cleanup: {left or 'none'}; stale ones removed at start: "
            f"{stale or 'none'}; harness time {time.monotonic() - started:.1f} s",
        ]
        if terminal is not None:
            terminal.write_line("\n".join(lines))
        assert left == [], f"namespaces not removed: {left}"

    request.addfinalizer(finish)
    d = Deployment(hosts, work, certs, other_ca, work / "laptop.mcap", Probe(), {})
    ready: dict[str, list[str]] = {"wearable": [], "laptop": []}
    d.router_lines = ready  # the routers' stdout: "ready", then Zenoh's warnings
    router_w = netns.config(netns.ROUTER_CONF, certs, "router", work, name="router-wearable")
    router_l = netns.config(
        netns.ROUTER_CONF, certs, "router", work, connect=[f"tls/{W}:7447"], name="router-laptop"
    )
    for host, config in (("wearable", router_w), ("laptop", router_l)):
        hosts.start(host, ["-m", "tests.multihost_node", "router", str(config)], name="router",
                    on_line=ready[host].append)  # fmt: skip
    netns.wait_until(
        lambda: all(any("ready" in ln for ln in v) for v in ready.values()), 30, "the routers"
    )
    d.start_service("laptop", "recorder", "recorder", ["--out", str(d.recording)])
    d.start_service("laptop", "foxglove_bridge", "foxglove", ["--port", "0"])
    # The wearable's own view of its bus: a viewer (allowed to subscribe, not to command).
    hosts.start("wearable", ["-m", "tests.multihost_node", "probe",
                             str(d.client_config("viewer", name="probe")), "lpc/**"],
                name="probe", on_line=d.probe)  # fmt: skip
    netns.wait_until(lambda: bool(d.probe.samples), 30, "the wearable's probe")
    for module, argv in WEARABLE.items():
        d.start_service("wearable", module, module, argv)

    def recording() -> bool:
        health = d.probe.of("lpc/health/recorder")
        return bool(health) and health[-1]["counters"].get("written", 0) > 1000

    def everything_up() -> bool:
        return all(d.probe.of(k) for k in ("lpc/prosthesis/command", "lpc/grasp/target"))

    up_s = netns.wait_until(lambda: everything_up() and recording(), 90, "the services")
    took = time.monotonic() - started
    report(f"setup: 2 routers, 2 laptop and {len(WEARABLE)} wearable services up in {took:.1f} s "
           f"({up_s:.1f} s of it waiting for the services)")  # fmt: skip
    yield d
    dead = {
        name: p.returncode
        for name, p in d.services.items()
        if p.poll() is not None and name not in d.stopped
    }
    assert dead == {}, f"services that exited by themselves: {dead}"


# --------------------------------------------------------------------------- intruders


def _intrude(d: Deployment, name: str, config: Path, *, edit: dict[str, str] | None = None) -> dict:
    if edit:
        text = config.read_text()
        for old, new in edit.items():
            assert old in text, old
            text = text.replace(old, new)
        config = d.work / f"intruder-{name}.json5"
        config.write_text(text)
    out: list[str] = []
    argv = ["-m", "tests.multihost_node", "intrude", str(config), "--as", name]
    process = d.hosts.start("intruder", argv, name=f"intrude-{name}", on_line=out.append)
    process.wait(60)
    netns.wait_until(lambda: bool(out), 5, f"intruder {name}'s report")
    result = json.loads(out[-1])
    # Zenoh's own warning (its log goes to stdout) names what failed in the handshake.
    reasons = re.findall(r"Unable to connect to \S+! (.*?) at /", _plain("".join(out)))
    result["reason"] = reasons[0] if reasons else result.get("error", "")
    return result


def _plain(text: str) -> str:
    return re.sub(r"\x1b\[[0-9;]*m", "", text)


def _router_refusals(d: Deployment) -> list[str]:
    """What the routers logged about refused links (their TLS layer's warnings)."""
    found = []
    for host, lines in d.router_lines.items():
        text = _plain("".join(lines))
        refused = re.findall(r"zenoh_link_tls::unicast: (.*?)\. Hint", text)
        found += [f"{host}: {m}" for m in refused]
    return sorted(set(found))


def test_multihost_intruders_are_kept_out(deployment: Deployment) -> None:
    d = deployment
    since = time.time_ns()
    wear, lap = f"tls/{W}:7447", f"tls/{L}:7447"
    other = {f'"{d.certs}/controller/': f'"{d.other_ca}/controller/'}
    attempts = {
        # (what it tries, the config) -> expected to connect?
        "another CA's certificate -> wearable": (
            d.client_config("controller", name="i1", connect=wear), other, False),
        "another CA's certificate -> laptop": (
            d.client_config("controller", name="i2", connect=lap), other, False),
        "no client certificate -> wearable": (
            d.client_config("controller", name="i3", connect=wear),
            {"enable_mtls: true": "enable_mtls: false"}, False),
        "plain TCP -> wearable": (
            d.client_config("controller", name="i4", connect=wear.replace("tls/", "tcp/")),
            {'protocols: ["tls"]': 'protocols: ["tcp"]'}, False),
        "role viewer -> wearable": (d.client_config("viewer", name="i5", connect=wear), None, True),
        "role viewer -> laptop": (d.client_config("viewer", name="i6", connect=lap), None, True),
        "unknown role stranger -> wearable": (
            d.client_config("stranger", name="i7", connect=wear), None, True),
    }  # fmt: skip
    results: dict[str, dict] = {}
    threads = []
    for i, (what, (config, edit, _)) in enumerate(attempts.items()):

        def go(
            what: str = what, config: Path = config, edit: dict | None = edit, i: int = i
        ) -> None:
            results[what] = _intrude(d, f"intruder{i}", config, edit=edit)

        threads.append(threading.Thread(target=go))
        threads[-1].start()
    for t in threads:
        t.join(90)
    # Markers after the intruders finished: anything they sent has arrived or been dropped
    # once the controller's next commands are seen.
    mark = time.time_ns()
    netns.wait_until(
        lambda: len(d.probe.of("lpc/prosthesis/command", mark)) > 20, 10, "commands after"
    )
    commands = d.probe.of("lpc/prosthesis/command", since)
    forged = [c for c in commands if str(c.get("source", "")).startswith("intruder")]
    lines = ["intruders:"]
    for what, (_, _, connects) in attempts.items():
        r = results[what]
        if not r["connected"]:
            stopped = f"refused: {r['reason'][:90]}"
        else:
            arrived = sum(c.get("source") == r["as"] for c in forged)
            stopped = (
                f"connected; sent {r['commands_sent']} hand commands, {arrived} reached the "
                f"wearable's bus (ACL: ingress put denied); received {r['received']} samples"
                + (" (ACL: subscribing denied)" if r["received"] == 0 else " (ACL: allowed)")
            )
        lines.append(f"  {what:<38} {stopped}")
        assert r["connected"] is connects, (what, r)
    lines.append(f"  the routers logged: {_router_refusals(d)}")
    report(*lines)
    assert forged == [], f"the bridge's side saw forged commands: {forged[:3]}"
    # The viewer may watch (the ACL's bus rule) but the unknown CN gets nothing at all.
    assert results["role viewer -> wearable"]["received"] > 0
    assert results["role viewer -> laptop"]["received"] > 0
    assert results["unknown role stranger -> wearable"]["received"] == 0


# --------------------------------------------------------------------------- recording


def _compare(
    d: Deployment, t0: int, t1: int, messages: list | None = None
) -> tuple[dict[str, int], dict[str, int], dict]:
    """Per key: published (seen on the wearable) and recorded, for messages stamped in
    [t0, t1], and the (key -> seqs) published but missing from the file."""
    published = d.probe.keys(t0, t1)
    recorded: dict[str, set[int]] = defaultdict(set)
    for m in d.recorded() if messages is None else messages:
        if t0 <= m.publish_time <= t1:
            recorded[m.key].add(m.sequence)
    missing = {
        k: sorted(seqs - recorded.get(k, set()))
        for k, seqs in published.items()
        if seqs - recorded.get(k, set())
    }
    return (
        {k: len(v) for k, v in published.items()},
        {k: len(recorded.get(k, set()) & v) for k, v in published.items()},
        missing,
    )


def test_multihost_the_laptop_records_every_topic_without_gaps(deployment: Deployment) -> None:
    d = deployment
    t0 = time.time_ns()
    time.sleep(STEADY_S)  # the run being recorded, not a synchronisation
    t1 = time.time_ns()
    # The file is read as it is written (up to its last finished chunk): once the recorder's
    # health reports from well after t1, read it, and again until it holds t1 + 1 s.
    netns.wait_until(lambda: bool(d.probe.of("lpc/health/recorder", t1 + 1_500_000_000)), 30,
                     "the recorder's health after the window")  # fmt: skip
    messages: list = []

    def complete() -> bool:
        messages[:] = d.recorded()
        return any(m.publish_time > t1 + 1e9 for m in messages)

    netns.wait_until(complete, 30, "the recording", 1.0)
    published, recorded, missing = _compare(d, t0, t1, messages)
    lines = [f"steady recording, {STEADY_S:.0f} s, camera set to 90 Hz: key, published -> recorded"]
    for key in sorted(published):
        lines.append(f"  {key:<32} {published[key]:>6} -> {recorded[key]:>6}")
    total = sum(published.values())
    lines.append(f"  total {total} -> {sum(recorded.values())}; missing: {missing or 'none'}")
    depth = sorted(d.probe.keys(t0, t1)["lpc/camera/depth"])
    lines.append(
        f"  depth seq {depth[0]}..{depth[-1]}: {len(depth)} frames, "
        f"{len(depth) / ((t1 - t0) / 1e9):.1f} Hz"
    )
    report(*lines)
    assert missing == {}
    for key in ("lpc/camera/depth", "lpc/scans", "lpc/emg", "lpc/prosthesis/command"):
        assert published.get(key, 0) > 0, key
    # The camera's own numbering has no holes: the wearable lost nothing either.
    assert depth == list(range(depth[0], depth[-1] + 1))


# --------------------------------------------------------------------------- cable cut


def _max_interval_ms(samples: list[dict]) -> float:
    times = sorted(s["r"] for s in samples)
    return max((b - a for a, b in itertools.pairwise(times)), default=0) / 1e6


def _counter(d: Deployment, service: str, name: str, before_ns: int) -> int:
    health = [h for h in d.probe.of(f"lpc/health/{service}") if h["r"] <= before_ns]
    return health[-1]["counters"].get(name, 0) if health else 0


def test_multihost_a_cut_cable_costs_the_wearable_nothing(deployment: Deployment) -> None:
    d = deployment
    # The stretch to compare with: the same length with the cable in, just before (the
    # deployment has been up longer than that).
    down = time.time_ns()
    before = down - int(CUT_S * 1e9)
    d.hosts.link("laptop", up=False)
    time.sleep(CUT_S)  # the cut itself
    d.hosts.link("laptop", up=True)
    up = time.time_ns()
    # Recording resumes by itself: the recorder logs the depth stream's gap when the first
    # frame after it arrives.
    netns.wait_until(
        lambda: any("gap on lpc/camera/depth" in g.get("text", "")
                    for g in d.probe.of("lpc/log/recorder", down)), 30, "the recorder's gap log",
    )  # fmt: skip
    # The gap is logged when the first frame after it is received; the file holds that frame
    # once its chunk is finished and written (on the recorder's writer thread), a moment later.
    netns.wait_until(
        lambda: any(m.key == "lpc/camera/depth" and m.log_time > up for m in d.recorded()),
        30, "a depth frame after the cut in the recording", 0.25,
    )  # fmt: skip
    gap_logs = [g["text"] for g in d.probe.of("lpc/log/recorder", down) if "gap" in g["text"]]
    wear_cmds = d.probe.of("lpc/prosthesis/command", down)
    during = [c for c in wear_cmds if c["r"] <= up]
    calm = [c for c in d.probe.of("lpc/prosthesis/command", before) if c["r"] <= down]

    def stops(t0: int, t1: int) -> list[dict]:
        return [
            s for s in d.controller_states(t0)
            if s["r"] <= t1 and s["state"] == "stopped" and s["previous"] != "stopped"
        ]  # fmt: skip

    stopped, stopped_before = stops(down, up + 500_000_000), stops(before, down)
    # The hand's watchdog: zero velocity when no fresh command came for 50 ms.
    watchdog = _counter(d, "prosthesis_bridge", "watchdog_stops", up + 2_000_000_000)
    watchdog0 = _counter(d, "prosthesis_bridge", "watchdog_stops", down)
    watchdog_before = _counter(d, "prosthesis_bridge", "watchdog_stops", before)
    recorded = d.recorded()
    # What the laptop lost: messages stamped from the cut until the link was back.
    published, kept, _ = _compare(d, down, up, recorded)
    resumed_s = (
        min(m.log_time for m in recorded if m.key == "lpc/camera/depth" and m.log_time > up) - up
    ) / 1e9
    depth_times = [m.log_time for m in recorded if m.key == "lpc/camera/depth"]
    # The file's own silence over the cut (receive times either side of it).
    depth_gap = [
        (a, b) for a, b in itertools.pairwise(depth_times) if b - a > 1e9 and a <= up and b >= down
    ]
    with contextlib.redirect_stdout(io.StringIO()) as out:
        assert lpc(["info", str(d.recording)]) == 0
    info = out.getvalue()
    info_gaps = [ln.strip() for ln in info.splitlines() if "gap" in ln]
    report(
        f"cable cut: laptop unplugged {CUT_S:.0f} s",
        f"  wearable, {CUT_S:.0f} s before the cut -> during it: hand commands {len(calm)} -> "
        f"{len(during)}, longest interval {_max_interval_ms(calm):.1f} -> "
        f"{_max_interval_ms(during):.1f} ms, controller stops {len(stopped_before)} -> "
        f"{len(stopped)} {[s['reason'] for s in stopped]}; bridge watchdog stops "
        f"{watchdog0 - watchdog_before} -> {watchdog - watchdog0}",
        f"  stamped during the cut: published {sum(published.values())}, recorded "
        f"{sum(kept.values())} (the rest dropped by the wearable's router, never waited for); "
        f"depth {published.get('lpc/camera/depth', 0)} -> {kept.get('lpc/camera/depth', 0)}, "
        f"hand commands {published.get('lpc/prosthesis/command', 0)} -> "
        f"{kept.get('lpc/prosthesis/command', 0)}",
        f"  recorder: resumed {resumed_s:.2f} s after "
        f"the link returned (depth after link-up in the file); depth silent over the cut "
        f"{[(b - a) / 1e9 for a, b in depth_gap]} s",
        f"  logged on lpc/log/recorder: {len(gap_logs)} gaps, e.g. {gap_logs[:2]}",
        f"  lpc info: {info_gaps[:3]}",
    )
    # Against the same stretch just before, not absolute figures: the machine may be loaded.
    # A router that waited for the unplugged laptop let a quarter of the commands through.
    assert len(during) >= 0.8 * len(calm), "the controller kept commanding"
    assert _max_interval_ms(during) < max(500.0, 1.5 * _max_interval_ms(calm))
    assert len(stopped) <= len(stopped_before), f"stops during the cut: {stopped}"
    assert depth_gap, "the file shows the silence of the cut"
    assert any("lpc/camera/depth" in g for g in gap_logs)
    assert any("gap on lpc/camera/depth" in g for g in info_gaps)


# --------------------------------------------------------------------------- offloaded


def test_multihost_offloaded_reconstruction_goes_stale_and_resumes(
    deployment: Deployment,
) -> None:
    d = deployment
    d.stopped.add("wearable/reconstructor")
    d.hosts.stop(d.services["wearable/reconstructor"])
    moved = time.time_ns()
    d.start_service("laptop", "reconstructor", "reconstructor", ["--method", "cloud"])
    # Wait for the controller to act on a target from the laptop. A pre-shape alone is not
    # enough: the wearable's last target stays fresh for the staleness threshold, and a
    # pre-shape on it (seen once in CI) comes before any target from the laptop. And it must
    # still be pre-shaping when the cable is cut: a new target sends it back to ready (CI at
    # e4257f7 cut the cable in ready, after a pre-shape on the laptop's target had ended).

    def preshaping_on_the_laptops_target() -> bool:
        targets = d.probe.of("lpc/grasp/target", moved)
        if not targets:
            return False
        states = d.controller_states(min(t["r"] for t in targets))
        return (
            any(s["state"] == "preshaping" and s["event"] == "auto_preshape" for s in states)
            and states[-1]["state"] == "preshaping"
        )

    netns.wait_until(preshaping_on_the_laptops_target, 60, "a pre-shape on the laptop's target")
    down = time.time_ns()
    d.hosts.link("laptop", up=False)
    last_target = max(t["r"] for t in d.probe.of("lpc/grasp/target", moved))
    limit_ns = last_target + int(STALE_TARGET_MS * 1e6)
    # The cut lasts until the controller has had its threshold and a second more to react.
    netns.wait_until(lambda: time.time_ns() > max(down + CUT_S * 1e9, limit_ns + 1e9), 10, "")
    up_ns = time.time_ns()
    d.hosts.link("laptop", up=True)
    transitions = [
        s for s in d.controller_states(down) if s["r"] < up_ns and s["event"] and s["previous"]
    ]
    commands = [c for c in d.probe.of("lpc/prosthesis/command", down) if c["r"] < up_ns]
    # Zero velocity from here on, until the link came back: the last moving command's successor.
    moving = [c for c in commands if c["grasp"] or c["wrist"]]
    zero_ns = next((c["r"] for c in commands if not moving or c["r"] > moving[-1]["r"]), None)
    assert zero_ns is not None, f"the hand was still commanded to move at link-up: {moving[-1]}"
    acting = [
        s for s in d.controller_states(limit_ns + 100_000_000)
        if s["r"] < up_ns and s["state"] in ("ready", "preshaping")
    ]  # fmt: skip
    netns.wait_until(
        lambda: any(s["state"] in ("ready", "preshaping") for s in d.controller_states(up_ns)),
        30,
        "the loop to resume",
    )
    resumed = next(s for s in d.controller_states(up_ns) if s["state"] in ("ready", "preshaping"))
    first_target = min(t["r"] for t in d.probe.of("lpc/grasp/target", up_ns))
    left = next((s for s in transitions if s["previous"] == "preshaping"), None)
    stale = [s for s in transitions if "lpc/grasp/target" in s["reason"]]
    stale_ms = f"{(stale[0]['r'] - down) / 1e6:.0f} ms" if stale else "(not: stopped before)"
    report(
        "offloaded reconstruction (cloud method on the laptop), cable cut during a pre-shape",
        f"  link-down -> stopped on the stale target {stale_ms}, -> hand zero velocity (held "
        f"until link-up) {(zero_ns - down) / 1e6:.0f} ms; last target -> zero velocity "
        f"{(zero_ns - last_target) / 1e6:.0f} ms (threshold {STALE_TARGET_MS:.0f} ms)",
        "  controller during the cut: "
        + "; ".join(
            f"+{(s['r'] - down) / 1e6:.0f} ms {s['previous']} -> {s['state']} ({s['reason']})"
            for s in transitions
        ),
        f"  link-up -> first grasp target {(first_target - up_ns) / 1e6:.0f} ms, -> controller "
        f"{resumed['state']} {(resumed['r'] - up_ns) / 1e6:.0f} ms; processes restarted: none",
    )
    assert left is not None, "the controller left pre-shaping"
    assert zero_ns <= limit_ns + 100_000_000, "zero velocity within the staleness threshold"
    assert acting == [], f"the controller acted on a stale target: {acting[:2]}"
    assert d.services["laptop/reconstructor"].poll() is None, "no restart was needed"


# --------------------------------------------------------------------------- cleanup


def test_multihost_namespaces_go_away_after_a_failure_and_after_a_kill(tmp_path: Path) -> None:
    reason = netns.unavailable()
    if reason:
        pytest.skip(reason)
    # A run that fails: close() (the fixture's finalizer) kills its processes, deletes all.
    hosts = netns.Hosts(tmp_path, names=["wearable"])
    sleeper = hosts.start("wearable", ["-c", "import time; time.sleep(60)"], name="sleeper")
    assert len(hosts.remaining()) == 2  # the host and the hub
    hosts.close()
    assert hosts.remaining() == [] and sleeper.poll() is not None
    # A run killed with SIGKILL leaves its namespaces; the next run removes them.
    code = (
        "import sys, time; from pathlib import Path; from tests import netns; "
        f"h = netns.Hosts(Path({str(tmp_path)!r}), names=['laptop']); "
        "print(h.tag, flush=True); time.sleep(60)"
    )
    killed = subprocess.Popen(
        [sys.executable, "-c", code], cwd=netns.ROOT, stdout=subprocess.PIPE, text=True
    )
    assert killed.stdout is not None
    tag = killed.stdout.readline().strip()
    killed.kill()
    killed.wait()
    left = [n for n in netns.ours() if n.startswith(tag + "-")]
    assert len(left) == 2
    assert sorted(netns.remove_stale()) == sorted(left)
    assert [n for n in netns.ours() if n.startswith(tag + "-")] == []
