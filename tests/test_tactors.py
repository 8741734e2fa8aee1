"""Tactor drivers: one contract run on each backend over a real pty, errors, profiles."""

from __future__ import annotations

import json
import os
import tty

import pytest

from lpc_core.devices.tactor_protocol import OFF, TactorOutput
from services.drivers import tactors
from services.drivers.errors import DeviceUnavailable, InitialisationError, OperationError
from services.drivers.tactor_sim import TactorSim
from services.drivers.tactors import (
    EaiDriver,
    LineDriver,
    TactorLink,
    load_profile,
    open_driver,
    tactor_profile,
)


@pytest.fixture(params=["sim", "line"])
def driver(request: pytest.FixtureRequest):
    d = open_driver(request.param)  # no port: a simulated controller on a pty
    yield d
    d.shutdown()


def test_driver_contract_send_reaches_controller(driver) -> None:
    driver.send(TactorOutput((0.0, 0.9, 0.0, 0.0)), timeout=1.0)
    assert driver.sim.wait_for(lambda s: s.mask == 0b0010, 2.0)
    assert driver.sim.levels[1] > 0.5


def test_driver_contract_recv_returns_ack_then_none_on_timeout(driver) -> None:
    driver.send(OFF)
    replies = []
    while (reply := driver.recv(0.2)) is not None:
        replies.append(reply)
    assert replies and all(r.ok for r in replies)
    assert driver.recv(0.0) is None


def test_driver_contract_shutdown_all_off_and_idempotent(driver) -> None:
    driver.send(TactorOutput((1.0, 1.0, 1.0, 1.0)))
    assert driver.sim.wait_for(lambda s: s.mask == 0b1111, 2.0)
    sim = driver.sim
    driver.shutdown()
    driver.shutdown()
    assert sim.mask == 0
    with pytest.raises(OperationError):
        driver.send(OFF)


@pytest.mark.parametrize("name", ["sim", "line"])
def test_driver_simulator_keeps_a_bounded_history(
    name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A service runs its simulated controller for hours: its record of the commands stays
    at the last ``SIM_HISTORY`` while the commands go on."""
    monkeypatch.setattr(tactors._OnSimulator, "SIM_HISTORY", 20)
    with open_driver(name) as d:
        for k in range(60):
            d.send(TactorOutput((0.0, 0.0, 0.0, 0.2 + 0.01 * k)))
        assert d.sim.wait_for(lambda s: s.levels[3] > 0.75, 2.0)
        assert len(d.sim.events) == 20
        assert d.sim.events[-1].levels[3] > 0.75


def test_driver_nak_is_received_as_a_reply() -> None:
    with open_driver("sim") as d:
        while d.recv(0.1) is not None:  # the start-up ACKs
            pass
        d.sim.nak_next = 1
        d.send(TactorOutput((0.5, 0, 0, 0)))
        replies = [d.recv(1.0) for _ in range(3)]  # frequency, gain, mask: the first is NAKed
        assert [r.ok for r in replies] == [False, True, True]
        assert replies[0].code == 5


def test_eai_driver_reads_firmware_version() -> None:
    with open_driver("sim") as d:
        assert isinstance(d, EaiDriver) and d.firmware == b"\x01\x00"


def test_driver_missing_port_is_unavailable() -> None:
    with pytest.raises(DeviceUnavailable, match="/nonexistent"):
        EaiDriver("/nonexistent/ttyUSB9")
    with pytest.raises(DeviceUnavailable, match="unknown tactor driver"):
        open_driver("bluetooth", "/dev/null")


@pytest.mark.parametrize("backend", [EaiDriver, LineDriver])
def test_driver_silent_device_fails_initialisation(backend) -> None:
    master, slave = os.openpty()  # a port with nothing behind it
    tty.setraw(slave)
    try:
        with pytest.raises(InitialisationError):
            backend(os.ttyname(slave), timeout=0.2)
    finally:
        os.close(master)
        os.close(slave)


def test_eai_driver_on_line_board_fails_initialisation() -> None:
    with TactorSim("line") as board, pytest.raises(InitialisationError):
        EaiDriver(board.port, timeout=0.3)


def test_sim_naks_garbage_with_bad_checksum_code() -> None:
    with TactorSim() as sim:
        fd = os.open(sim.port, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, bytes.fromhex("02 00 80 01 05 00 03"))  # checksum should be 6C
            assert sim.wait_for(lambda s: len(s.events) == 1, 2.0)
            assert not sim.events[0].ok and sim.mask == 0
        finally:
            os.close(fd)


def test_link_counts_acks_and_naks() -> None:
    link = TactorLink(lambda: open_driver("sim"))
    try:
        assert link.reopen(0)
        assert link.write(TactorOutput((0.5, 0.5, 0, 0))) == "ok"
        assert link.driver.sim.wait_for(lambda s: s.mask == 0b0011, 2.0)
        assert link.write(OFF) == "ok"
        assert link.counters["writes"] == 2 and link.counters["naks"] == 0
    finally:
        link.close()


def test_profile_absent_default_is_empty_and_explicit_must_exist(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    assert load_profile(None) == {}
    with pytest.raises(ValueError, match="does not exist"):
        load_profile(tmp_path / "nope.json")


def test_profile_gain_limits_loaded(tmp_path) -> None:
    path = tmp_path / "profile.json"
    section = {"gain_min": [0.1, 0.2, 0.3, 0.4], "gain_max": [0.9, 1, 1, 0.8], "arm": "left"}
    path.write_text(json.dumps({"emg": {"rest": 0.01}, "tactors": section}))
    profile = tactor_profile(load_profile(path))
    assert profile.gain_min == (0.1, 0.2, 0.3, 0.4)
    assert profile.gain_max == (0.9, 1.0, 1.0, 0.8)
    path.write_text(json.dumps({"tactors": {"gain_max": [2, 1, 1, 1]}}))
    with pytest.raises(ValueError, match="gain_max"):
        tactor_profile(load_profile(path))
    path.write_text("{not json")
    with pytest.raises(ValueError, match="JSON"):
        load_profile(path)


def test_link_nak_sends_all_off_and_asks_for_a_rewrite() -> None:
    link = TactorLink(lambda: open_driver("sim"))
    try:
        assert link.reopen(0)
        sim = link.driver.sim
        assert link.write(TactorOutput((0.5, 0, 0, 0))) == "ok"
        assert sim.wait_for(lambda s: s.mask == 0b0001, 2.0)
        sim.nak_next = 1
        status = link.write(TactorOutput((0, 0.5, 0, 0)))
        assert sim.wait_for(lambda s: any(not e.ok for e in s.events), 2.0)
        if status == "ok":  # the NAK came back after the write returned: the next write sees it
            status = link.write(TactorOutput((0, 0.5, 0, 0)))
        assert status == "reset"
        assert sim.wait_for(lambda s: s.mask == 0 and s.events[-1].command == 0x00, 2.0)
        assert link.counters["naks"] == 1
    finally:
        link.close()
