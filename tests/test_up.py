"""``lpc up`` end to end: the service set on the simulated scene, recorded to MCAP."""

from __future__ import annotations

import collections
import subprocess
import sys
from pathlib import Path

import pytest

from services.cli.up import SERVICES
from services.mcap_log import McapLog
from tests.conftest import free_port

DURATION_S = 4.0


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess, Path]:
    out = tmp_path_factory.mktemp("up") / "session.mcap"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "up",
            "--source",
            "sim",
            "--duration",
            str(DURATION_S),
            "--record",
            str(out),
            "--port",
            str(free_port()),
            # The frame-slot count below is the camera's pacing; on a loaded machine the
            # controller's late ticks would rightly shed frames (tests/test_camera_shedding.py).
            "--no-shed",
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    return result, out


def test_up_exits_zero_and_every_service_stopped_cleanly(session) -> None:
    result, _ = session
    assert result.returncode == 0, result.stderr[-3000:]
    assert "summary" in result.stderr


def test_up_records_every_message_decodable(session) -> None:
    _, out = session
    counts: collections.Counter[str] = collections.Counter()
    with McapLog(out) as log:
        for item in log.messages(None, decode=True):
            assert not item.error, f"{item.key}: {item.error}"
            counts[item.key] += 1
        assert log.cut is None
    for name in SERVICES:
        if name != "foxglove":
            assert counts[f"lpc/health/{name}"] >= 2, name
    # Nearly every frame slot is filled: the camera may skip a few while processes warm up.
    assert counts["lpc/camera/depth"] >= 0.8 * 90 * DURATION_S
    assert counts["lpc/scans"] >= 0.95 * counts["lpc/camera/depth"]


def test_up_recorder_loses_nothing(session) -> None:
    """The recorder writes every message it receives, and every message of the FIFO topics
    (commands and states, which block rather than drop) a service says it published is in the
    file (final health is recorded, because the recorder is stopped last). Sensor topics drop
    under congestion rather than stall the camera: a frame dropped on the way never reaches
    the recorder, so the file may lack a few depth frames, which stay rare."""
    _, out = session
    counts: collections.Counter[str] = collections.Counter()
    logged: dict[str, list[tuple[int, int]]] = collections.defaultdict(list)
    final: dict[str, object] = {}
    with McapLog(out) as log:
        for item in log.messages(None, decode=True):
            counts[item.key] += 1
            logged[item.key].append((item.log_time, item.message.seq))
            if item.key.startswith("lpc/health/"):
                final[item.message.service] = item.message
    recorder = final["recorder"]
    assert recorder.counters.get("dropped", 0) == 0
    assert recorder.counters["received"] == recorder.counters["written"]
    # A FIFO topic has no gap once every service is up (the camera starts last): before, the
    # controller publishes while the peers are still finding their routes to each other.
    settled = min(t for t, _ in logged["lpc/camera/depth"]) + 500_000_000
    for key in ("lpc/controller/state", "lpc/prosthesis/command"):
        seqs = sorted(n for t, n in logged[key] if t >= settled)
        assert len(seqs) > 20 and seqs == list(range(seqs[0], seqs[0] + len(seqs))), key
    for service, key in (("camera", "lpc/camera/depth"), ("scans", "lpc/scans")):
        published = final[service].counters["published"]
        assert published - 0.02 * published <= counts[key] <= published, (service, published)


def test_up_rejects_bad_parameters() -> None:
    for argv, needle in [
        (["--duration", "-1"], "--duration must be positive"),
        (["--source", "replay"], "needs the recording"),
        (["--source", "webcam"], "must be sim, sim-device, realsense or replay"),
        (["--services", "nope"], "unknown service"),
    ]:
        result = subprocess.run(
            [sys.executable, "-m", "services.cli", "up", *argv],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert result.returncode == 2
        assert needle in result.stderr
        assert "Traceback" not in result.stderr
