"""lpc_core.gaps: silences of steady topics and seq jumps, as the recorder and lpc info see them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lpc_core.gaps import SOURCE_SEQ_KEYS, Gap, GapParams, GapState, gap_step, gap_steps

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


@dataclasses.dataclass(frozen=True)
class _RefTrack:
    seq: int
    last_ns: int
    period_ns: float | None
    count: int


def _reference_step(
    params: GapParams, tracks: dict[str, _RefTrack], key: str, seq: int, t_ns: int
) -> list[Gap]:
    """The tracker as first written (one record per key, replaced on every message): the model
    ``gap_step``'s cheaper state must agree with."""
    track = tracks.get(key)
    if track is None:
        tracks[key] = _RefTrack(seq, t_ns, None, 1)
        return []
    dt = t_ns - track.last_ns
    missing = seq - track.seq - 1 if seq > track.seq and key not in SOURCE_SEQ_KEYS else 0
    steady = (
        track.period_ns is not None
        and track.count >= params.steady_count
        and track.period_ns <= 1e9 / params.steady_hz
        and not key.startswith("lpc/log/")
    )
    silent = steady and dt > max(
        params.min_silence_ms * 1e6, params.silence_periods * track.period_ns
    )
    period = track.period_ns
    if not silent:
        period = float(dt) if period is None else 0.9 * period + 0.1 * dt
    tracks[key] = _RefTrack(seq, t_ns, period, track.count + 1)
    return [Gap(key, track.last_ns, t_ns, missing, silent)] if silent or missing > 0 else []


def _random_stream(rng: np.random.Generator, n: int) -> list[tuple[str, int, int]]:
    """Steady, slow, log and source-seq topics; cuts, mutes, losses, repeats and restarts."""
    keys = ["lpc/camera/depth", "lpc/emg", "lpc/reconstruction", "lpc/grasp/target"]
    keys += ["lpc/health/emg", "lpc/log/controller", "lpc/hand/state"]
    weights = np.array([30, 30, 10, 10, 0.3, 2, 20])
    seqs = dict.fromkeys(keys, 0)
    muted_until = dict.fromkeys(keys, 0)
    t_ns, stream = 0, []
    while len(stream) < n:
        t_ns += int(rng.integers(0, 3 * MS))
        if rng.random() < 2e-4:
            t_ns += int(rng.integers(100, 4000)) * MS  # the cable cut: everything falls silent
        key = keys[rng.choice(len(keys), p=weights / weights.sum())]
        if t_ns < muted_until[key]:
            continue
        if rng.random() < 3e-4:
            muted_until[key] = t_ns + int(rng.integers(50, 3000)) * MS
        event = rng.random()
        if event < 0.01:
            seqs[key] += int(rng.integers(2, 9))  # lost on the way (or frames skipped)
        elif event < 0.013:
            pass  # the same seq again
        elif event < 0.015:
            seqs[key] = 1  # the publisher restarted
        elif event < 0.017:
            seqs[key] = int(rng.integers(1, seqs[key] + 2))  # back somewhere
        else:
            seqs[key] += 1
        stream.append((key, seqs[key], t_ns))
    return stream


@pytest.mark.parametrize("seed", range(4))
def test_gaps_step_agrees_with_the_reference_on_random_streams(seed: int) -> None:
    rng = np.random.default_rng(seed)
    params = GapParams(steady_count=int(rng.integers(5, 30)), min_silence_ms=rng.uniform(50, 600))
    stream = _random_stream(rng, 20_000)
    state, ref_tracks, ref_gaps, ref_missing = GapState(params=params), {}, 0, 0
    kept, kept_tracks, silent, jumps = None, None, 0, 0
    for i, (key, seq, t_ns) in enumerate(stream):
        expected = _reference_step(params, ref_tracks, key, seq, t_ns)
        state, gaps = gap_step(state, key, seq, t_ns)
        assert gaps == expected, (i, key, seq, t_ns)
        ref_gaps += len(expected)
        ref_missing += sum(g.missing for g in expected)
        silent += sum(g.silent for g in expected)
        jumps += sum(not g.silent for g in expected)
        assert (state.gaps, state.missing) == (ref_gaps, ref_missing)
        assert state.params is params
        tracks = {k: (r.seq, r.last_ns, r.period_ns, r.count) for k, r in ref_tracks.items()}
        assert dict(state.tracks) == tracks, i
        if i == len(stream) // 2:
            kept, kept_tracks = state, tracks
    # Every kind of gap came up, and no step changed the state it was given: the one from the
    # middle is as it was, and replays to the same end.
    assert silent > 3 and jumps > 3
    assert kept is not None and dict(kept.tracks) == kept_tracks
    replayed = kept
    for key, seq, t_ns in stream[len(stream) // 2 + 1 :]:
        replayed, _ = gap_step(replayed, key, seq, t_ns)
    assert replayed == state


def test_gaps_step_agrees_with_the_reference_where_the_pace_is_not_a_number() -> None:
    # Messages all at one time have period 0, and an infinite silence_periods makes 0 * inf:
    # the floor (min_silence_ms) decides, as max(floor, nan) does.
    params = GapParams(silence_periods=float("inf"))
    stream = [("lpc/emg", s, 0) for s in range(1, 31)] + [("lpc/emg", 31, 2000 * MS)]
    state, ref_tracks = GapState(params=params), {}
    for key, seq, t_ns in stream:
        state, gaps = gap_step(state, key, seq, t_ns)
        assert gaps == _reference_step(params, ref_tracks, key, seq, t_ns)
    assert [(g.silent, g.start_ns, g.end_ns) for g in gaps] == [(True, 0, 2000 * MS)]


@pytest.mark.parametrize("seed", range(2))
def test_gap_steps_over_batches_agree_with_the_reference(seed: int) -> None:
    # The recorder's batches (one a hand-over, from one message to thousands): the gaps in
    # order and each batch's end state are the reference's after the same messages.
    rng = np.random.default_rng(10 + seed)
    params = GapParams(steady_count=int(rng.integers(5, 30)), min_silence_ms=rng.uniform(50, 600))
    stream = _random_stream(rng, 20_000)
    cuts = np.sort(rng.choice(np.arange(1, len(stream)), size=200, replace=False))
    state, ref_tracks, ref_gaps, ref_missing, found = GapState(params=params), {}, 0, 0, 0
    for batch in np.split(np.arange(len(stream)), cuts):
        messages = [stream[i] for i in batch]
        expected = [g for m in messages for g in _reference_step(params, ref_tracks, *m)]
        before, before_tracks = state, dict(state.tracks)
        state, gaps = gap_steps(state, messages)
        assert gaps == expected
        ref_gaps += len(expected)
        ref_missing += sum(g.missing for g in expected)
        found += len(expected)
        assert (state.gaps, state.missing, state.params) == (ref_gaps, ref_missing, params)
        tracks = {k: (r.seq, r.last_ns, r.period_ns, r.count) for k, r in ref_tracks.items()}
        assert dict(state.tracks) == tracks
        assert dict(before.tracks) == before_tracks  # the state it was given is unchanged
    assert found > 10
    assert gap_steps(state, []) == (state, [])
