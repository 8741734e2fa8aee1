"""The camera's frame gate (``lpc_core.perception.shedding``): scripted health reports and
frames in, the gate's verdicts and the allowed rate out. No bus, no clock."""

from __future__ import annotations

import itertools
import math

import pytest

from lpc_core.perception.shedding import (
    FrameReady,
    Gate,
    RateChange,
    ShedParams,
    ShedState,
    shed_step,
)
from schemas import Health

S = 1_000_000_000
FRAME_NS = round(S / 90)


def report(service: str, ticks: int, late: int) -> Health:
    return Health(
        seq=1, t_ns=0, service=service, pid=1, counters={"ticks": ticks, "late_ticks": late}
    )


def frames(state: ShedState, start_ns: int, n: int, period_ns: int = FRAME_NS):
    """``n`` frames from ``start_ns``: the state after them and which were published."""
    kept = []
    for i in range(n):
        state, gate = shed_step(state, FrameReady(), start_ns + i * period_ns)
        kept.append(gate is Gate.PUBLISH)
    return state, kept


def overloaded(rate_hz: float = 90.0) -> ShedState:
    """The controller's baseline at 0 s, then two seconds with 40 % of its ticks late: the
    rate is halved at 2 s."""
    state = ShedState(ShedParams(max_rate_hz=rate_hz))
    state, _ = shed_step(state, report("controller", 100, 0), 0)
    state, change = shed_step(state, report("controller", 200, 40), 1 * S)
    assert change is None and not state.shedding
    state, change = shed_step(state, report("controller", 300, 80), 2 * S)
    assert change == RateChange(rate_hz, rate_hz / 2, 0.4, "controller")
    return state


def test_shed_step_passes_every_frame_while_the_control_path_is_on_time() -> None:
    state = ShedState(ShedParams(max_rate_hz=90.0))
    state, kept = frames(state, 0, 45)
    for second in range(1, 4):  # 1 % late: under clean_below
        state, change = shed_step(state, report("controller", 100 * second, second), second * S)
        assert change is None
    state, more = frames(state, 4 * S, 45)
    assert all(kept + more)
    assert state.shed_frames == 0 and state.rate == 90.0 and not state.shedding


def test_shed_step_halves_the_rate_when_too_many_ticks_are_late_twice_in_a_row() -> None:
    state = overloaded()
    assert state.rate == 45.0 and state.shedding


def test_shed_step_takes_one_late_window_for_a_passing_burst() -> None:
    state = ShedState(ShedParams(max_rate_hz=90.0))
    state, _ = shed_step(state, report("controller", 100, 0), 0)
    for second, late in enumerate((90, 95, 180, 185, 280), start=1):  # late every other second
        state, change = shed_step(state, report("controller", 100 * (second + 1), late), second * S)
        assert change is None
    assert not state.shedding
    state, kept = frames(state, 6 * S, 90)
    assert all(kept)


def test_shed_step_keeps_frames_evenly_at_the_allowed_rate() -> None:
    state = overloaded()  # 45 Hz of a 90 Hz camera: every other frame
    state, kept = frames(state, 2 * S, 90)
    assert sum(kept) == 45 and state.shed_frames == 45
    assert all(a != b for a, b in itertools.pairwise(kept))
    # Jitter of a tenth of a period does not cost frames: still one in two.
    jittered = ShedState(ShedParams(max_rate_hz=90.0), rate_hz=45.0)
    t, kept = 0, []
    for i in range(90):
        t += FRAME_NS + (FRAME_NS // 10 if i % 2 else -(FRAME_NS // 10))
        jittered, gate = shed_step(jittered, FrameReady(), t)
        kept.append(gate is Gate.PUBLISH)
    assert sum(kept) == 45


def test_shed_step_decreases_once_per_report_window_whoever_reports() -> None:
    state = ShedState(ShedParams(max_rate_hz=90.0))
    state, _ = shed_step(state, report("controller", 100, 0), 0)
    state, _ = shed_step(state, report("other", 100, 0), S // 2)
    state, _ = shed_step(state, report("controller", 200, 50), 1 * S)
    state, _ = shed_step(state, report("other", 200, 60), 3 * S // 2)
    state, _ = shed_step(state, report("controller", 300, 100), 2 * S)
    assert state.rate == 45.0
    # The other's window began at 1.5 s, before the decrease at 2 s: it saw the old rate.
    state, change = shed_step(state, report("other", 300, 120), 5 * S // 2)
    assert change is None and state.rate == 45.0
    # The controller's next window began at the decrease: still late, so halve again.
    state, change = shed_step(state, report("controller", 400, 150), 3 * S)
    assert change == RateChange(45.0, 22.5, 0.5, "controller")
    # And the other's, which began at 2.5 s, before that one.
    state, change = shed_step(state, report("other", 400, 180), 7 * S // 2)
    assert change is None and state.rate == 22.5


def test_shed_step_holds_between_the_thresholds_and_climbs_when_clean() -> None:
    state = overloaded()
    state, change = shed_step(state, report("controller", 400, 105), 3 * S)  # 25 %: hold
    assert change is None and state.rate == 45.0
    # 10 %: climbs a tenth of the rate a second (more than 1 Hz at 45 Hz).
    state, change = shed_step(state, report("controller", 500, 115), 4 * S)
    assert change == RateChange(45.0, 49.5, 0.1, "controller")
    # A clean window of 1.5 s adds 1.5 times that.
    state, change = shed_step(state, report("controller", 650, 115), 11 * S // 2)
    assert change is not None and change.rate_hz == pytest.approx(49.5 + 1.5 * 4.95)


def test_shed_step_climbs_one_hz_a_second_at_low_rates() -> None:
    state = overloaded(10.0)  # 5 Hz: a tenth would be 0.5 Hz a second
    state, change = shed_step(state, report("controller", 400, 80), 3 * S)
    assert change == RateChange(5.0, 6.0, 0.0, "controller")


def test_shed_step_climbs_back_to_every_frame() -> None:
    state = overloaded(10.0)
    assert state.rate == 5.0
    for second in range(3, 9):
        state, _ = shed_step(state, report("controller", 100 * (second + 1), 80), second * S)
    assert state.rate == 10.0 and not state.shedding
    state, kept = frames(state, 9 * S, 30, period_ns=S // 10)
    assert all(kept)


def test_shed_step_never_goes_under_the_least_rate() -> None:
    state = ShedState(ShedParams(max_rate_hz=90.0, min_rate_hz=5.0))
    state, _ = shed_step(state, report("controller", 0, 0), 0)
    for second in range(1, 10):
        state, _ = shed_step(state, report("controller", 100 * second, 90 * second), second * S)
    assert state.rate == 5.0
    state, kept = frames(state, 10 * S, 90)
    assert sum(kept) == 5


def test_shed_step_climbs_back_when_the_reports_stop() -> None:
    state = overloaded()  # 45 Hz at 2 s; the controller then goes silent
    state, _ = frames(state, 2 * S, 2 * 90)
    assert state.rate == 45.0  # silent for 2 s: not stale yet (3 s)
    state, _ = frames(state, 4 * S, 2 * 90)  # stale from 5 s: a tenth a second since
    assert state.rate == pytest.approx(45.0 * math.exp(0.1), abs=0.1)
    for second in range(6, 60):
        state, _ = frames(state, second * S, 90)
    assert state.rate == 90.0


def test_shed_step_takes_a_restarted_service_as_a_new_baseline() -> None:
    state = overloaded()
    state, change = shed_step(state, report("controller", 50, 40), 3 * S)  # counters restart
    assert change is None and state.rate == 45.0
    state, change = shed_step(state, report("controller", 150, 40), 4 * S)
    assert change == RateChange(45.0, 49.5, 0.0, "controller")


def test_shed_step_ignores_services_without_tick_counters() -> None:
    state = ShedState(ShedParams(max_rate_hz=90.0))
    recorder = Health(seq=1, t_ns=0, service="recorder", pid=1, counters={"dropped": 9})
    state, change = shed_step(state, recorder, 0)
    assert change is None and state.reports == {}


def test_shed_step_settles_where_the_control_path_keeps_its_rate() -> None:
    # The share of the controller's ticks more than 10 ms late against the camera's rate, as
    # measured with lpc bench footprint --together --record --cpus 0.5 (device at a fixed rate,
    # nothing shed): 5 Hz 14 %, 10 Hz 26 %, 15 Hz 38 %, 20 Hz 51 %; hand commands kept 100 Hz
    # up to 10 Hz (108, 100, 90, 81 Hz). Fed that, the gate settles in its hold band: late
    # in 20-30 % of the ticks, 7.4-11.5 Hz here.
    def late_share(rate_hz: float) -> float:
        return 0.14 + (rate_hz - 5.0) * (0.51 - 0.14) / 15.0

    state = ShedState(ShedParams(max_rate_hz=90.0))
    ticks = late = 0
    state, _ = shed_step(state, report("controller", ticks, late), 0)
    rates = []
    for second in range(1, 121):
        state, kept = frames(state, (second - 1) * S, 90)
        ticks += 100
        late += round(100 * late_share(sum(kept)))
        state, _ = shed_step(state, report("controller", ticks, late), second * S)
        rates.append(state.rate)
    assert rates[:4] == [90.0, 45.0, 22.5, 11.25]  # late twice, then halved each second
    settled = rates[30:]
    assert min(settled) >= 7.4 and max(settled) <= 11.5


def test_shed_params_reject_bad_values() -> None:
    with pytest.raises(ValueError, match="min_rate_hz"):
        ShedParams(max_rate_hz=10.0, min_rate_hz=20.0)
    with pytest.raises(ValueError, match="clean_below"):
        ShedParams(clean_below=0.5, late_above=0.3)
    with pytest.raises(ValueError, match="decrease"):
        ShedParams(decrease=1.0)
    with pytest.raises(ValueError, match="increase_hz_per_s"):
        ShedParams(increase_hz_per_s=0.0)
    with pytest.raises(TypeError, match="FrameReady"):
        shed_step(ShedState(), "frame", 0)  # type: ignore[arg-type]


def test_shed_step_keeps_the_allowed_rate_between_divisors_of_the_camera_rate() -> None:
    # The credit a passed frame leaves over is kept: 40 Hz of a 90 Hz camera keeps 40 frames a
    # second, not the 30 (every third frame) that capping the credit at one frame kept.
    for rate_hz, expected in ((40.0, 40), (25.0, 25), (18.0, 18), (61.0, 61)):
        state = ShedState(ShedParams(max_rate_hz=90.0), rate_hz=rate_hz, credit=0.0)
        state, kept = frames(state, 0, 900)
        assert abs(sum(kept) - 10 * expected) <= 1, rate_hz
        # Never two in a row below half the camera's rate: spread evenly.
        if rate_hz < 45:
            assert not any(a and b for a, b in itertools.pairwise(kept))
    # After a pause, one frame passes and no burst follows.
    state = ShedState(ShedParams(max_rate_hz=90.0), rate_hz=30.0)
    state, kept = frames(state, 0, 3)
    state, late = frames(state, 10 * S, 4)
    assert late == [True, False, True, False]
