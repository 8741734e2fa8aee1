"""lpc_core.gaps: silences of steady topics and seq jumps, as the recorder and lpc info see them."""

from __future__ import annotations

import pytest

from lpc_core.gaps import GapParams, GapState, gap_step

MS = 1_000_000


def _run(stream: list[tuple[str, int, int]]) -> tuple[GapState, list]:
    state, found = GapState(), []
    for key, seq, t_ns in stream:
        state, gaps = gap_step(state, key, seq, t_ns)
        found += gaps
    return state, found


def test_gaps_a_cut_link_is_one_silence_with_its_losses() -> None:
    # 90 Hz for 1 s, nothing for 3 s, then on again with 5 frames lost on the way.
    times = [i * 11 * MS for i in range(90)]
    stream = [("lpc/camera/depth", i + 1, t) for i, t in enumerate(times)]
    resume = times[-1] + 3000 * MS
    stream += [("lpc/camera/depth", 96 + i, resume + i * 11 * MS) for i in range(10)]
    state, gaps = _run(stream)
    assert len(gaps) == 1
    gap = gaps[0]
    assert (gap.silent, gap.missing, gap.start_ns, gap.end_ns) == (True, 5, times[-1], resume)
    assert gap.duration_s == pytest.approx(3.0)
    assert (state.gaps, state.missing) == (1, 5)
    assert "silent 3.000 s, 5 missing by seq" in gap.describe()


def test_gaps_slow_topics_logs_and_source_seq_keys_are_not_losses() -> None:
    stream = [("lpc/health/emg", i + 1, i * 1000 * MS) for i in range(30)]  # 1 Hz: not steady
    stream += [("lpc/log/x", i + 1, i * MS) for i in range(30)] + [("lpc/log/x", 31, 5000 * MS)]
    stream += [("lpc/grasp/target", s, s * 11 * MS) for s in (1, 4, 9, 10)]  # skipped frames
    _, gaps = _run(stream)
    assert gaps == []


def test_gaps_a_seq_jump_without_silence_and_a_restart() -> None:
    stream = [("lpc/emg", s, s * 10 * MS) for s in (1, 2, 3, 7, 8)]
    stream += [("lpc/emg", 1, 90 * MS)]  # the publisher restarted: seq starts over, no loss
    _, gaps = _run(stream)
    assert [(g.missing, g.silent) for g in gaps] == [(3, False)]


def test_gaps_params_are_checked() -> None:
    with pytest.raises(ValueError, match="min_silence_ms"):
        GapParams(min_silence_ms=0)
