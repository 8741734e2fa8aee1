"""The control loop's tick paced by the hand's status (lpc_core.control.pacing)."""

from __future__ import annotations

import numpy as np

from lpc_core.control.pacing import PACE_WINDOW_NS, pace

P = 10_000_000
W = PACE_WINDOW_NS


def run_ticks(stream: list[int], until_ns: int) -> tuple[list[int], list[bool]]:
    """The ticks of a timer as ``services.runtime.Ticks`` runs it, nominally from 0 every
    period, with the pacing samples received at ``stream``: their times and which fired with
    a sample."""
    fired: list[int] = []
    paced: list[bool] = []
    t_ns, i, previous = P, 0, None
    while t_ns < until_ns:
        running = previous is not None and t_ns - previous <= 2 * P
        due = t_ns + W if running else t_ns
        at = None
        while i < len(stream) and stream[i] <= due:
            got = pace(P, t_ns, previous, stream[i])
            previous, i = stream[i], i + 1
            if got is None:
                continue
            if got[1] == previous:
                t_ns, at = got
                break
            t_ns, due = got  # brought forward
        fired.append(at if at is not None else t_ns)
        paced.append(at is not None)
        t_ns += P
    return fired, paced


def test_pace_ticks_meet_a_stream_at_their_rate_within_a_few_periods() -> None:
    """A status 4 ms after the ticks (a hand started at another moment) is met within
    ``period / window`` periods; from then on every tick fires with a status, at its receive
    time, and no interval leaves the window."""
    rng = np.random.default_rng(0)
    stream = [int(4_000_000 + k * P + rng.normal(0, 300_000)) for k in range(100)]
    fired, paced = run_ticks(stream, 99 * P)
    assert all(paced[5:])
    assert not any(paced[:2])
    assert set(fired[5:]) <= set(stream)
    gaps = np.diff(fired)
    assert gaps.min() >= P - 2 * W and gaps.max() <= P + 2 * W


def test_pace_ticks_keep_their_rate_whatever_the_streams() -> None:
    """A hand slowed to 84 Hz, one at 200 Hz, none: 100 ticks a second within 1 %; a faster
    stream fires them at its samples but never more often."""
    second = 100 * P
    for hz in (84.0, 200.0):
        stream = [int(1_300_000 + k * 1e9 / hz) for k in range(int(hz) + 10)]
        fired, paced = run_ticks(stream, second + P // 2)
        assert 99 <= len(fired) <= 101
        assert np.diff(fired).min() >= P - 2 * W
        assert any(paced)
    fired, paced = run_ticks([], second + P // 2)
    assert fired == [k * P for k in range(1, 101)] and not any(paced)


def test_pace_sample_outside_the_window() -> None:
    """Early from a stream at another rate, or late: nothing; early at the tick's rate: the
    timer a window earlier; within the window: now, the nominal time moved by W/20 at most."""
    t = 100 * P
    assert pace(P, t, None, t - 5_000_000) is None
    assert pace(P, t, t - 5_000_000 - 12_000_000, t - 5_000_000) is None
    assert pace(P, t, t - 5_000_000 - P, t - 5_000_000) == (t - W, t - W)
    assert pace(P, t, None, t + W + 1) is None
    assert pace(P, t, None, t + 1_500_000) == (t + W // 20, t + 1_500_000)
    assert pace(P, t, None, t - 50_000) == (t - 50_000, t - 50_000)
