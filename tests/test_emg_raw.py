"""Raw EMG sources for real: a pylsl outlet in another process, BrainFlow's synthetic board.

LSL discovery is confined to this machine (scope ``machine``: queries to 127.0.0.1 only), in
this process and in the outlet's.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from schemas import EmgSample
from services.drivers.emg_lsl_sim import GAIN, SIM_ENVELOPE_V
from services.drivers.emg_raw import BrainFlowEmg, LslEmg, brainflow_board_id, import_pylsl
from services.drivers.errors import DeviceUnavailable, InitialisationError, OperationError
from tests.conftest import Listener, spawn_service, wait_for

MAV = np.sqrt(2 / np.pi)  # mean absolute value of a unit Gaussian


def _outlet(name: str, rate: float = 2000.0, pause: float = 2.0) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-m", "services.drivers.emg_lsl_sim", "--name", name]
    command += ["--rate", str(rate), "--duration", "120", "--pause", str(pause)]
    return subprocess.Popen(
        [*command, "--scope", "machine"],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )


@pytest.fixture
def outlet() -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    name = f"lpc-test-{uuid.uuid4().hex[:8]}"
    process = _outlet(name)
    assert process.stdout is not None
    assert b"open" in process.stdout.readline()  # the outlet exists before anyone looks
    try:
        yield name, process
    finally:
        process.terminate()
        process.wait(timeout=10)


def test_lsl_emg_maps_the_asked_channels(outlet: tuple[str, subprocess.Popen[bytes]]) -> None:
    name, _ = outlet
    source = LslEmg((1, 3), name=name, timeout=10.0, scope="machine")
    try:
        assert source.rate_hz == 2000.0
        assert name in source.description
        chunks, deadline = [], time.monotonic() + 20.0
        while sum(len(c) for c, _ in chunks) < 4000 and time.monotonic() < deadline:
            got = source.recv(timeout=0.1)
            if got is not None:
                chunks.append(got)
        samples = np.concatenate([c for c, _ in chunks])
        assert samples.shape[1] == 2 and len(samples) >= 4000
        stamps = [t for _, t in chunks]
        assert stamps == sorted(stamps)
        # Channel 3 carries the hum and offset only; channel 1 the same plus noise at half the
        # flexor's envelope, whose RMS over whole periods is sqrt(mean^2 + swing^2 / 2).
        mean, swing = SIM_ENVELOPE_V
        expected = GAIN[1] * np.sqrt(mean**2 + swing**2 / 2)
        assert abs(np.std(samples[:, 0] - samples[:, 1]) / expected - 1.0) < 0.1
        hum = samples[:, 1] - samples[:, 1].mean()
        assert 0.9 < np.std(hum) / (3e-4 / np.sqrt(2)) < 1.1
    finally:
        source.shutdown()
        source.shutdown()  # twice is safe


def _recv_some(source: LslEmg, timeout: float = 20.0) -> np.ndarray:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = source.recv(timeout=0.1)
        if got is not None:
            return got[0]
    pytest.fail(f"no samples within {timeout} s")


def test_lsl_emg_resolves_again_after_a_long_silence(
    outlet: tuple[str, subprocess.Popen[bytes]],
) -> None:
    name, process = outlet
    source = LslEmg(name=name, timeout=10.0, scope="machine", reresolve_s=0.5)
    try:
        _recv_some(source)
        process.send_signal(signal.SIGUSR1)  # the outlet goes away for 2 s
        deadline = time.monotonic() + 20.0
        with pytest.raises(OperationError, match=r"no samples for 0\.5 s: resolving again"):
            while time.monotonic() < deadline:
                source.recv(timeout=0.1)
    finally:
        source.shutdown()
    again = LslEmg(name=name, timeout=20.0, scope="machine")  # found once the outlet is back
    try:
        assert _recv_some(again).shape[1] == 2
    finally:
        again.shutdown()


def test_lsl_emg_resolve_times_out_with_a_clear_message() -> None:
    start = time.monotonic()
    with pytest.raises(DeviceUnavailable, match="no LSL stream with name 'lpc-nobody'"):
        LslEmg(name="lpc-nobody", timeout=0.5, scope="machine")
    assert time.monotonic() - start < 10.0


def test_lsl_emg_rejects_streams_too_slow_or_too_narrow() -> None:
    pylsl = import_pylsl("machine")
    name = f"lpc-slow-{uuid.uuid4().hex[:8]}"
    info = pylsl.StreamInfo(name, "EMG", 2, 50.0, pylsl.cf_float32, name)
    outlet = pylsl.StreamOutlet(info)
    try:
        with pytest.raises(InitialisationError, match="50 Hz: raw EMG needs"):
            LslEmg(name=name, timeout=10.0, scope="machine")
        with pytest.raises(InitialisationError, match="has 2 channels"):
            LslEmg((0, 2), name=name, timeout=10.0, scope="machine")
    finally:
        del outlet


def test_emg_service_over_lsl_degrades_and_resumes(
    rendezvous: zenoh.Session, endpoint: str, outlet: tuple[str, subprocess.Popen[bytes]]
) -> None:
    name, source = outlet
    keys = ("lpc/emg", "lpc/health/emg", "lpc/log/emg")
    listen = Listener(rendezvous, *keys)
    process = spawn_service(
        "services.emg",
        endpoint,
        *("--source", "lsl", "--lsl-stream", name, "--lsl-scope", "machine"),
        *("--channels", "0", "1", "--lsl-timeout", "20"),
    )
    emg: list[EmgSample] = listen.messages["lpc/emg"]
    health = listen.messages["lpc/health/emg"]
    try:
        wait_for(lambda: len(emg) > 450, 60.0, "4.5 s of envelopes")
        samples = np.array([s.channels for s in emg[50:450]])  # two periods of the envelope
        # The envelope of Gaussian EMG is its mean absolute value; the sim's mean std is known.
        assert abs(samples[:, 0].mean() / (SIM_ENVELOPE_V[0] * MAV) - 1.0) < 0.1
        assert abs(samples[:, 1].mean() / samples[:, 0].mean() - GAIN[1]) < 0.03
        assert all(s.source == "lsl" and s.unit == "raw" for s in emg)
        t_ns = np.array([s.t_ns for s in emg])
        assert np.all(np.diff(t_ns) > 0)
        assert abs(np.median(np.diff(t_ns)) / 1e6 - 10.0) < 0.5

        # The outlet disappears for 2 s and comes back (same source id).
        logs = listen.messages["lpc/log/emg"]

        def gaps_ms() -> list[float]:
            texts = [m.text for m in logs if "EMG samples resumed after" in m.text]
            return [float(t.split("after ")[1].split(" ms")[0]) for t in texts]

        cut = len(health)
        source.send_signal(signal.SIGUSR1)
        wait_for(lambda: max(gaps_ms(), default=0.0) >= 2000.0, 60.0, "resumed after 2 s")
        back, resumed_at = len(emg), len(health)
        wait_for(lambda: len(emg) > back + 100, 30.0, "a second of EMG after the outage")
        wait_for(lambda: any(h.status == "ok" for h in health[resumed_at:]), 30.0, "ok health")
        assert any(h.status == "degraded" for h in health[cut:resumed_at])
        # Every outage is logged and counted (a loaded machine may add short ones of its own).
        degraded = [m for m in logs if "no EMG samples for 250 ms: degraded" in m.text]
        assert 1 <= len(gaps_ms()) <= len(degraded) <= len(gaps_ms()) + 1
        assert 1 <= health[-1].counters.get("emg_outages", 0) <= len(degraded)
        arrivals = np.diff(listen.received_ns["lpc/emg"]) / 1e6
        assert arrivals.max() >= 2000.0  # and nothing was published meanwhile
        assert np.all(np.diff([s.seq for s in emg]) > 0)  # seq goes on across the outage
    finally:
        process.send_signal(signal.SIGINT)
        process.wait(timeout=20)
        listen.close()
    assert process.returncode == 0


def test_brainflow_board_names() -> None:
    assert brainflow_board_id("synthetic") == -1
    assert brainflow_board_id("cyton") == 0 == brainflow_board_id("CYTON_BOARD")
    assert brainflow_board_id("ganglion") == 1
    assert brainflow_board_id("cyton-daisy") == 2
    assert brainflow_board_id("-1") == -1
    with pytest.raises(DeviceUnavailable, match="knows no board 'toaster'"):
        brainflow_board_id("toaster")


def test_brainflow_synthetic_board_gives_chunks_at_its_rate() -> None:
    source = BrainFlowEmg((0, 1), board="synthetic")
    try:
        assert source.rate_hz == 250.0
        n, first, deadline = 0, None, time.monotonic() + 20.0
        while n < 500 and time.monotonic() < deadline:
            got = source.recv(timeout=0.1)
            if got is not None:
                samples, t_ns = got
                assert samples.ndim == 2 and samples.shape[1] == 2
                assert np.all(np.isfinite(samples))
                first = first or t_ns
                n += len(samples)
        assert n >= 500
    finally:
        source.shutdown()
        source.shutdown()


def test_brainflow_errors_are_driver_errors() -> None:
    with pytest.raises(InitialisationError, match="16 EMG channels"):
        BrainFlowEmg((0, 20), board="synthetic")
    # A Cyton on a port that does not exist: BrainFlow's error, as DeviceUnavailable.
    with pytest.raises(DeviceUnavailable, match="cannot start BrainFlow board 'cyton'"):
        BrainFlowEmg((0, 1), board="cyton", serial_port=os.devnull + "-missing")


def test_emg_service_over_brainflow_publishes_envelopes(
    rendezvous: zenoh.Session, endpoint: str
) -> None:
    listen = Listener(rendezvous, "lpc/emg", "lpc/log/emg")
    process = spawn_service(
        "services.emg", endpoint, "--source", "brainflow", "--board", "synthetic", "--mains", "60"
    )
    emg: list[EmgSample] = listen.messages["lpc/emg"]
    try:
        wait_for(lambda: len(emg) > 300, 60.0, "3 s of envelopes")
        values = np.array([s.channels for s in emg[50:300]])
        # Rectified and smoothed: never negative; exactly zero only where the filter starts
        # afresh (its first output, after an outage on a loaded machine).
        assert values.shape[1] == 2 and np.all(values >= 0) and np.mean(values > 0) > 0.95
        assert all(s.source == "brainflow" and s.unit == "uV" for s in emg)
        t_ns = np.array([s.t_ns for s in emg])
        # 250 Hz in, one output per 2.5 samples: 8 and 12 ms apart, 10 ms on average.
        gaps_ms = np.diff(t_ns[50:300]) / 1e6
        assert abs(gaps_ms.mean() - 10.0) < 0.5 and np.all(gaps_ms > 0)
        texts = [m.text for m in listen.messages["lpc/log/emg"]]
        assert any("clamped to 112.5 Hz (rate 250 Hz)" in t for t in texts)
    finally:
        process.send_signal(signal.SIGINT)
        process.wait(timeout=20)
        listen.close()
    assert process.returncode == 0
