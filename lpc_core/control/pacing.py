"""A periodic tick paced by a stream at its own rate (the hand's status at 100 Hz).

The control loop's 10 ms tick (the simulated user's EMG sample, the controller's stale check)
and the hand's status both wake the loop a hundred times a second; with unrelated phases that
is two wake-ups every period. A tick may instead fire when a status sample arrives within
``window_ns`` of the tick's nominal time, at that sample's receive time, in the wake-up the
sample costs anyway. The nominal times keep the tick's period (a hand slowed to 84 Hz does not
slow the EMG samples); without samples the tick keeps its own time.

Pure: the caller's timer asks what a sample means and schedules accordingly.
"""

from __future__ import annotations

# How far a paced tick may fire from its nominal time: under 5 ms, so that one status paces at
# most one tick and two ticks stay 2 ms apart. The hand's status reaches the control loop
# 4.5-16 ms apart (10th-90th percentile, lpc bench footprint at load 8-10): within 2 ms of
# the nominal tick for 48 % of the ticks.
PACE_WINDOW_NS = 4_000_000


def pace(
    period_ns: int,
    t_ns: int,
    previous_ns: int | None,
    received_ns: int,
    window_ns: int = PACE_WINDOW_NS,
) -> tuple[int, int] | None:
    """What a pacing sample received at ``received_ns`` (the stream's previous one at
    ``previous_ns``, ``None`` if none) does to the tick nominally at ``t_ns``, as
    ``(nominal, at)``: the tick's nominal time from now on and when it fires; ``None``: the
    sample changes nothing (the timer fires at the nominal time).

    Within the window the tick fires now, at the sample's receive time, and its nominal time
    moves a twentieth of the window towards it: the ticks meet the stream's phase in the middle
    of the window, while their rate stays within 2 % of the period whatever the stream's rate.
    Earlier, a sample of a stream at the tick's rate (its period within a quarter window)
    brings the timer forward by a window: such a stream meets the ticks within
    ``period / window`` periods, and a stream at another rate never moves them.
    """
    offset = received_ns - t_ns
    if -window_ns <= offset <= window_ns:
        step = window_ns // 20
        return t_ns + min(max(offset, -step), step), received_ns
    if (
        offset < 0
        and previous_ns is not None
        and abs(received_ns - previous_ns - period_ns) <= window_ns // 4
    ):
        return t_ns - window_ns, t_ns - window_ns
    return None
