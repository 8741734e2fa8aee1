"""``lpc info``: a summary of a real MCAP file, complete or cut short."""

from __future__ import annotations

from pathlib import Path

import pytest

from schemas import EmgSample, Health, ProsthesisState, encode
from services.cli import info
from services.cli import main as lpc
from services.mcap_log import LogWriter

T0 = 1_700_000_000_000_000_000


def write_log(path: Path, seconds: float = 2.0, *, junk: bool = False) -> None:
    """EMG at 100 Hz, prosthesis state at 50 Hz, health at 1 Hz; tiny chunks so cuts land
    between many of them."""
    with LogWriter(path, chunk_bytes=4096, compression="lz4") as writer:
        for i in range(int(seconds * 100)):
            t = T0 + i * 10_000_000
            writer.write("lpc/emg", EmgSample(seq=i, t_ns=t, channels=[0.1, 0.2]), t + 1000)
            if i % 2 == 0:
                state = ProsthesisState(seq=i, t_ns=t, wrist_angle_deg=1.0, aperture_mm=50.0)
                writer.write("lpc/prosthesis/state", state, t + 2000)
            if i % 100 == 0:
                health = Health(seq=i, t_ns=t, service="emg", pid=1)
                writer.write("lpc/health/emg", health, t + 3000)
        if junk:
            writer.write_received("lpc/emg", b"\xc1", T0 + 5)


def rows(text: str) -> dict[str, list[str]]:
    return {line.split()[0]: line.split() for line in text.splitlines() if line.startswith("lpc/")}


def test_info_lists_topics_counts_rates_and_duration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_log(tmp_path / "s.mcap")
    assert lpc(["info", str(tmp_path / "s.mcap")]) == 0
    out = capsys.readouterr().out
    table = rows(out)
    assert set(table) == {"lpc/emg", "lpc/prosthesis/state", "lpc/health/emg"}
    _, count, rate, first, last, schema = table["lpc/emg"]
    assert (count, schema) == ("200", "EmgSample")
    assert float(rate) == pytest.approx(100.0, abs=0.01)
    assert (float(first), float(last)) == (0.0, pytest.approx(1.99, abs=1e-6))
    assert float(table["lpc/prosthesis/state"][2]) == pytest.approx(50.0, abs=0.01)
    assert table["lpc/health/emg"][1:3] == ["2", "1.00"]
    assert "duration     1.990 s" in out
    assert "messages     302 on 3 topics" in out
    assert "compression lz4, complete" in out
    assert "note:" not in out


def test_info_cut_short_file_says_where(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_log(tmp_path / "s.mcap")
    data = (tmp_path / "s.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    assert lpc(["info", str(tmp_path / "cut.mcap")]) == 0
    out = capsys.readouterr().out
    assert "CUT SHORT" in out
    note = [line for line in out.splitlines() if line.startswith("note:")]
    assert len(note) == 1 and "cut short at byte" in note[0] and "last good time" in note[0]
    count = int(rows(out)["lpc/emg"][1])
    assert 0 < count < 200


def test_info_validate_flags_undecodable_messages(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_log(tmp_path / "good.mcap", 0.5)
    assert lpc(["info", "--validate", str(tmp_path / "good.mcap")]) == 0
    write_log(tmp_path / "junk.mcap", 0.5, junk=True)
    assert lpc(["info", "--validate", str(tmp_path / "junk.mcap")]) == 1
    table = rows(capsys.readouterr().out)
    assert table["lpc/_rejected/lpc/emg"][6] == "1"
    assert table["lpc/emg"][6] == "0"


def test_info_not_an_mcap_file_is_an_error_without_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "x.mcap").write_bytes(encode(EmgSample(seq=0, t_ns=0, channels=[])))
    assert lpc(["info", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert "not an MCAP file" in err and "Traceback" not in err


@pytest.mark.parametrize("gap_slice", [4096, 7])
def test_info_says_where_the_gaps_are(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    gap_slice: int,
) -> None:
    # EMG at 100 Hz for 1 s, a 3 s hole, then on again with two samples lost on the way;
    # stepped whole and in slices of 7 (the hole falls inside one), the same gap.
    monkeypatch.setattr(info, "_GAP_SLICE", gap_slice)
    path = tmp_path / "gap.mcap"
    with LogWriter(path) as writer:
        for seq in [*range(1, 101), *range(103, 153)]:
            t = T0 + seq * 10_000_000 + (3_000_000_000 if seq > 100 else 0)
            writer.write("lpc/emg", EmgSample(seq=seq, t_ns=t, channels=[0.1, 0.2]), t)
    assert lpc(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "gaps         1 (1 silences), 2 messages missing by seq" in out
    assert "gap on lpc/emg from 0.990 s: silent 3.030 s, 2 missing by seq" in out
