"""``lpc bench latency``: the frame-to-serial matching, and a short smoke run end to end."""

from __future__ import annotations

import argparse

import pytest

from lpc_core.devices.tactor_protocol import Command
from services.cli.bench import latency as bench_latency
from services.drivers.tactor_sim import SimEvent

MS = 1_000_000


def write(t_ns: int, mask: int, command: int = Command.SET_TACTORS) -> SimEvent:
    return SimEvent(arrival_ns=t_ns, command=command, ok=True, mask=mask, levels=(0.0,) * 4)


def test_match_serial_pairs_each_frame_with_its_mask() -> None:
    period = 11 * MS
    captures = [(0, 0b0001), (period, 0b0011), (2 * period, 0b0010)]
    events = [
        write(3 * MS, 0b0001),
        write(4 * MS, 0b0001, command=Command.GAIN),  # not a mask write
        write(period + 5 * MS, 0b0011),
        # frame 2's bytes never come; a much later write of its mask is out of the window
        write(2 * period + 8 * period + 1, 0b0010),
    ]
    assert bench_latency.match_serial(captures, events, period) == pytest.approx([3.0, 5.0])


def test_scene_masks_follow_the_default_placement() -> None:
    # Right, down-right, down, ...: single tactors on the axes, pairs on the diagonals.
    assert [bin(m).count("1") for m in bench_latency.MASKS] == [1, 2] * 4
    assert len(bench_latency.scene(bench_latency.Intrinsics())) == bench_latency.DIRECTIONS


def test_bench_latency_smoke_run_prints_figures(capsys) -> None:
    parser = argparse.ArgumentParser()
    bench_latency.add_arguments(parser)
    code = bench_latency.run(parser.parse_args(["--duration", "0.5", "--warmup", "0.3"]))
    out = capsys.readouterr().out
    assert code == 0, out
    assert "bytes on the serial line" in out and "p99" in out
