"""The tactor bridge: its step under a scripted clock, and the service over a real pty."""

from __future__ import annotations

import signal
import time

import pytest
import zenoh

from lpc_core.devices.tactor_bridge import (
    PORT_OPENED,
    TICK,
    BridgeParams,
    BridgeState,
    TactorProfile,
    bridge_step,
)
from lpc_core.devices.tactor_protocol import OFF, TactorOutput
from schemas import TactorCommand, encode
from services.drivers.tactor_sim import TactorSim
from services.drivers.tactors import SimDriver, TactorLink
from tests.conftest import spawn_service, wait_for

MS = 1_000_000
T0 = 1_000_000 * MS


def command(*amplitudes: float, t_ns: int = T0, pulse: bool = False) -> TactorCommand:
    return TactorCommand(seq=1, t_ns=t_ns, amplitudes=list(amplitudes), pulse=pulse)


def out(*levels: float) -> TactorOutput:
    return TactorOutput(tuple(levels))


def test_bridge_step_first_command_written_at_once() -> None:
    state, outputs = bridge_step(BridgeState(), command(0.7, 0.0, 0.0, 0.0), T0 + 3 * MS)
    assert outputs == [out(0.7, 0, 0, 0)]
    assert state.wake_ns == T0 + 100 * MS + 1  # the cue's staleness is the next event


def test_bridge_step_stale_cue_switches_all_off() -> None:
    state, _ = bridge_step(BridgeState(), command(0.5, 0.5, 0, 0), T0 + 2 * MS)
    state, outputs = bridge_step(state, TICK, T0 + 100 * MS)
    assert outputs == []  # exactly 100 ms old: still valid
    state, outputs = bridge_step(state, TICK, state.wake_ns)
    assert outputs == [OFF]


def test_bridge_step_stale_from_receipt_ignores_capture_clock() -> None:
    params = BridgeParams(stale_from="receipt")
    old = command(0.5, 0, 0, 0, t_ns=5)  # a replay's capture time, from another clock
    state, outputs = bridge_step(BridgeState(params=params), old, T0)
    assert outputs == [out(0.5, 0, 0, 0)]
    state, outputs = bridge_step(state, TICK, T0 + 101 * MS)
    assert outputs == [OFF]


def test_bridge_step_command_already_stale_on_arrival_is_off() -> None:
    _, outputs = bridge_step(BridgeState(), command(1, 1, 1, 1), T0 + 150 * MS)
    assert outputs == [OFF]


def test_bridge_step_rate_limit_holds_then_writes_newest() -> None:
    state = BridgeState(params=BridgeParams(burst=1))  # one write per 5 ms, no saving up
    state, _ = bridge_step(state, command(0.2, 0, 0, 0), T0)
    state, outputs = bridge_step(state, command(0.4, 0, 0, 0, t_ns=T0 + 1 * MS), T0 + 1 * MS)
    assert outputs == []
    state, outputs = bridge_step(state, command(0.6, 0, 0, 0, t_ns=T0 + 2 * MS), T0 + 2 * MS)
    assert outputs == [] and state.wake_ns == T0 + 5 * MS
    state, outputs = bridge_step(state, TICK, state.wake_ns)
    assert outputs == [out(0.6, 0, 0, 0)]


def test_bridge_step_rate_limit_lets_a_short_burst_through() -> None:
    # Frames bunched by jitter pass at once; a flood is cut to the token rate (5 ms).
    state, written = BridgeState(), []
    for i in range(6):
        t = T0 + i * MS // 2
        state, outputs = bridge_step(state, command(0.1 * (i + 1), 0, 0, 0, t_ns=t), t)
        written += outputs
    assert [o.levels[0] for o in written] == pytest.approx([0.1, 0.2, 0.3])
    # Three tokens spent by 1 ms; the bucket refills one token per 5 ms from there.
    assert state.wake_ns == T0 + 5 * MS
    state, outputs = bridge_step(state, TICK, state.wake_ns)
    assert [o.levels[0] for o in outputs] == pytest.approx([0.6])


def test_bridge_step_refreshes_unchanged_output() -> None:
    state, outputs = bridge_step(BridgeState(), TICK, T0)
    assert outputs == [OFF]  # nothing received yet: all off, written once at start
    assert state.wake_ns == T0 + 200 * MS
    state, outputs = bridge_step(state, TICK, T0 + 100 * MS)
    assert outputs == []
    _, outputs = bridge_step(state, TICK, T0 + 200 * MS)
    assert outputs == [OFF]


def test_bridge_step_pulse_alternates_on_and_off() -> None:
    params = BridgeParams(stale_ns=10_000 * MS)
    state, outputs = bridge_step(BridgeState(params=params), command(1, 1, 1, 1, pulse=True), T0)
    assert outputs == [out(1, 1, 1, 1)]
    assert state.wake_ns == T0 + 150 * MS
    seen = []
    for t in (T0 + 150 * MS, T0 + 300 * MS, T0 + 450 * MS):
        state, outputs = bridge_step(state, TICK, t)
        seen += outputs
    assert seen == [OFF, out(1, 1, 1, 1), OFF]
    # A repeated pulsing command keeps the phase instead of restarting it.
    state, outputs = bridge_step(state, command(1, 1, 1, 1, pulse=True), T0 + 500 * MS)
    assert outputs == []


def test_bridge_step_port_opened_rewrites_at_once() -> None:
    state, _ = bridge_step(BridgeState(), command(0.3, 0, 0, 0), T0)
    state, outputs = bridge_step(state, PORT_OPENED, T0 + 1 * MS)
    assert outputs == [out(0.3, 0, 0, 0)]


def test_bridge_step_applies_gain_limits() -> None:
    profile = TactorProfile(gain_min=(0.2, 0.2, 0.2, 0.2), gain_max=(0.6, 1.0, 1.0, 1.0))
    params = BridgeParams(profile=profile)
    _, outputs = bridge_step(BridgeState(params=params), command(0.5, 0.5, 0, 1.0), T0)
    # 0.2 + 0.5 * 0.4 = 0.4; 0.2 + 0.5 * 0.8 = 0.6; zero stays off; 0.2 + 1.0 * 0.8 = 1.0
    assert outputs[0].levels == pytest.approx((0.4, 0.6, 0.0, 1.0))


def test_bridge_params_reject_bad_values() -> None:
    with pytest.raises(ValueError, match="stale_ns"):
        BridgeParams(stale_ns=0)
    with pytest.raises(ValueError, match="gain_min"):
        TactorProfile(gain_min=(0.5,) * 4, gain_max=(0.4,) * 4)


def test_bridge_over_pty_stale_cue_reaches_the_controller_as_all_off() -> None:
    # The step under a scripted clock, its outputs written through the real pty.
    link = TactorLink(SimDriver)
    try:
        assert link.reopen(T0)
        sim = link.driver.sim
        state, outputs = bridge_step(BridgeState(), command(0.9, 0.0, 0.0, 0.0), T0)
        for o in outputs:
            assert link.write(o) == "ok"
        assert sim.wait_for(lambda s: s.mask == 0b0001 and s.gain == 3, 2.0)
        state, outputs = bridge_step(state, TICK, T0 + 101 * MS)
        for o in outputs:
            assert link.write(o) == "ok"
        assert sim.wait_for(lambda s: s.mask == 0 and s.events[-1].command == 0x00, 2.0)
    finally:
        link.close()


def test_bridge_link_all_off_on_error_and_reopens_when_port_returns(tmp_path) -> None:
    # A stable name for a port that comes and goes, as udev's /dev/serial/by-id/ links are.
    port = tmp_path / "ttyTACTOR"
    first = TactorSim()
    port.symlink_to(first.port)
    from services.drivers.tactors import EaiDriver

    link = TactorLink(lambda: EaiDriver(str(port)), retry_ns=100 * MS)
    second = None
    try:
        assert link.reopen(T0)
        assert link.write(out(0.5, 0.5, 0, 0)) == "ok"
        assert first.wait_for(lambda s: s.mask == 0b0011, 2.0)
        first.close()  # unplugged
        port.unlink()
        assert link.write(out(0.5, 0, 0, 0)) == "down"
        assert not link.up and link.counters["errors"] == 1
        assert not link.reopen(T0 + 50 * MS)  # retry not due yet
        assert not link.reopen(T0 + 100 * MS)  # due, but the port is still gone
        assert link.counters["open_failures"] == 1
        second = TactorSim()
        port.symlink_to(second.port)  # plugged back in
        assert link.reopen(T0 + 200 * MS)
        assert link.write(out(0, 0, 0.5, 0)) == "ok"
        assert second.wait_for(lambda s: s.mask == 0b0100, 2.0)
    finally:
        link.close()
        if second is not None:
            second.close()


def test_bridge_link_notices_a_port_that_hangs_up_while_idle() -> None:
    # Nothing to write (the cue has not changed): the poll of the replies finds the hang-up.
    from services.drivers.tactors import EaiDriver

    sim = TactorSim()
    link = TactorLink(lambda: EaiDriver(sim.port), retry_ns=100 * MS)
    try:
        assert link.reopen(T0)
        assert link.write(out(0.5, 0, 0, 0)) == "ok"
        assert link.poll() == "ok" and link.up
        sim.close()
        assert link.poll() == "down"
        assert not link.up and link.counters["errors"] == 1
        assert "read from" in link.last_error
        assert link.poll() == "down"  # down stays down until reopened
    finally:
        link.close()


def _put(session: zenoh.Session, message: TactorCommand) -> None:
    session.put("lpc/tactors/command", encode(message))


def _light(session: zenoh.Session, sim: TactorSim, mask: int) -> bool:
    amplitudes = [0.8 if mask >> k & 1 else 0.0 for k in range(4)]
    _put(session, command(*amplitudes, t_ns=time.time_ns()))
    return sim.wait_for(lambda s: s.mask == mask, 0.05)


def test_bridge_service_switches_off_when_cues_stop(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    sim = TactorSim()
    proc = spawn_service("services.tactor_bridge", endpoint, "--tactor-port", sim.port)
    try:
        assert sim.wait_for(lambda s: s.bytes_received > 0, 30.0), "bridge never opened the port"
        wait_for(lambda: _light(rendezvous, sim, 0b0010), 20.0, "tactor 1 on")
        # No more cues: once the last is 100 ms old the controller goes all off.
        assert sim.wait_for(lambda s: s.mask == 0, 5.0)
        assert sim.events[-1].command == 0x00
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        sim.close()


def test_bridge_service_switches_off_on_shutdown(endpoint: str, rendezvous: zenoh.Session) -> None:
    sim = TactorSim()
    # A cue that never goes stale: the all-off can only come from the shutdown.
    proc = spawn_service(
        "services.tactor_bridge", endpoint, "--tactor-port", sim.port, "--stale-ms", "60000"
    )
    try:
        assert sim.wait_for(lambda s: s.bytes_received > 0, 30.0), "bridge never opened the port"
        wait_for(lambda: _light(rendezvous, sim, 0b1000), 20.0, "tactor 3 on")
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        assert sim.mask == 0 and sim.events[-1].command == 0x00
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        sim.close()


def test_bridge_service_reconnects_when_the_port_comes_back(
    endpoint: str, rendezvous: zenoh.Session, tmp_path
) -> None:
    port = tmp_path / "ttyTACTOR"
    first = TactorSim()
    port.symlink_to(first.port)
    proc = spawn_service(
        "services.tactor_bridge", endpoint, "--tactor-port", str(port), "--stale-ms", "60000"
    )
    second = None
    try:
        assert first.wait_for(lambda s: s.bytes_received > 0, 30.0), "bridge never opened"
        wait_for(lambda: _light(rendezvous, first, 0b0001), 20.0, "tactor 0 on")
        first.close()  # unplugged: the next write fails, the port is gone
        port.unlink()
        second = TactorSim()
        port.symlink_to(second.port)  # plugged back in under the same name
        wait_for(lambda: _light(rendezvous, second, 0b0100), 20.0, "tactor 2 on the new port")
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        first.close()
        if second is not None:
            second.close()
