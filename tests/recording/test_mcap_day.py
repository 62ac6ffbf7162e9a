"""Reading recorded days: real MCAP files read back, and broken."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from recorded_days import PERIOD, T0, scan

from softsensor.errors import IngestError
from softsensor.recording.day_writer import DayWriter
from softsensor.recording.mcap_day import iter_messages, read_day
from softsensor.signals import SCAN_SIGNALS, TOPIC_HEALTH, TOPIC_LAB, TOPIC_SCAN


def test_round_trip(day: Path) -> None:
    d = read_day(day)
    assert not d.truncated
    assert list(d.scans.columns) == list(SCAN_SIGNALS)
    assert d.scans.index.dtype == np.int64
    assert len(d.scans) == 600
    assert d.scans.index[0] == T0 and d.scans.index[-1] == T0 + 599 * PERIOD
    assert d.scans["T_air_in"].iloc[5] == pytest.approx(300.05)
    assert list(d.labs.columns) == ["log_time_ns", "sample_time_ns", "moisture_out", "sample_id"]
    assert list(d.labs["sample_id"]) == ["L100", "L300", "L500"]
    assert d.labs["log_time_ns"].is_monotonic_increasing
    assert d.labs["sample_time_ns"].iloc[0] == T0 - 80 * PERIOD
    assert [lab.sample_id for lab in d.lab_results()] == ["L100", "L300", "L500"]
    assert len(d.topic(TOPIC_HEALTH)) == 10
    assert d.topic(TOPIC_HEALTH)[0] == (T0, {"status": "ok", "detail": "fine"})
    assert d.topic("/nothing") == []
    assert d.truth is not None
    assert list(d.truth.index) == [T0, T0 + 600 * 10**9]
    assert d.truth["moisture_in"].tolist() == [1.0, 1.1]
    assert "note" not in d.truth.columns
    assert math.isnan(d.truth["T_wall"].iloc[0])
    assert d.start_ns == T0


def test_topic_selection_and_no_truth(day: Path) -> None:
    d = read_day(day, topics=[TOPIC_SCAN])
    assert len(d.scans) == 600 and len(d.labs) == 0 and d.truth is None
    assert d.topics == [TOPIC_SCAN]


def test_iter_messages_in_log_time_order(tmp_path: Path) -> None:
    path = tmp_path / "order.mcap"
    with DayWriter(path, chunk_size=256) as w:
        for t in [5, 3, 9, 1, 7]:
            w.write(TOPIC_HEALTH, T0 + t, {"status": "ok", "detail": str(t)})
        w.write(TOPIC_SCAN, T0 + 4, {"T_amb": 280.0})
    got = list(iter_messages(path))
    assert [t - T0 for _, t, _ in got] == [1, 3, 4, 5, 7, 9]
    got = list(iter_messages(path, topics=[TOPIC_HEALTH], start_ns=T0 + 3, end_ns=T0 + 9))
    assert [b["detail"] for _, _, b in got] == ["3", "5", "7"]


def test_truncated_file(day: Path, tmp_path: Path) -> None:
    data = day.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(IngestError, match=r"cut\.mcap: truncated"):
        read_day(cut)
    with pytest.raises(IngestError, match="truncated"):
        list(iter_messages(cut))
    d = read_day(cut, allow_truncated=True)
    assert d.truncated
    assert 100 < len(d.scans) < 600
    # every message read is intact and the first ones are all there
    full = read_day(day)
    n = len(d.scans)
    assert d.scans.equals(full.scans.iloc[:n])
    streamed = list(iter_messages(cut, topics=[TOPIC_SCAN], allow_truncated=True))
    assert len(streamed) == n


def test_cut_just_before_footer(day: Path, tmp_path: Path) -> None:
    data = day.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:-5])
    with pytest.raises(IngestError):
        read_day(cut)
    d = read_day(cut, allow_truncated=True)
    assert d.truncated and len(d.scans) == 600


def test_not_an_mcap(tmp_path: Path) -> None:
    bad = tmp_path / "notes.mcap"
    bad.write_text("T_air_in,m_air\n450,80\n" * 20)
    with pytest.raises(IngestError, match=r"notes\.mcap: not an MCAP file"):
        read_day(bad)
    with pytest.raises(IngestError, match="not an MCAP"):
        read_day(bad, allow_truncated=True)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(IngestError, match=r"empty\.mcap"):
        read_day(empty)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(IngestError, match=r"nope\.mcap: no such file"):
        read_day(tmp_path / "nope.mcap")
    with pytest.raises(IngestError, match="is a directory"):
        read_day(tmp_path)


def test_corrupt_chunk(day: Path, tmp_path: Path) -> None:
    with open(day, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[3]
    data = bytearray(day.read_bytes())
    mid = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[mid:mid + 16] = b"\x55" * 16
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(IngestError, match=r"bad\.mcap: corrupt MCAP"):
        read_day(bad)


def test_cut_file_with_a_garbage_chunk_length_reads_its_intact_part(day: Path,
                                                                      tmp_path: Path) -> None:
    """A crash can leave a chunk header whose length field is garbage (found by
    benchmarks/soak.py): the intact messages before it are read, the garbage length is not
    allocated (it was a MemoryError)."""
    with open(day, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[3]
    data = bytearray(day.read_bytes()[:chunk.chunk_start_offset + chunk.chunk_length])
    # a chunk record: opcode (1), record length (8), start and end times (8 + 8),
    # uncompressed size (8) and crc (4), the compression name (4 + len), the data length (8)
    with open(day, "rb") as f:
        compression = make_reader(f).get_summary().chunk_indexes[3].compression
    length_at = chunk.chunk_start_offset + 1 + 8 + 28 + 4 + len(compression)
    assert int.from_bytes(data[length_at:length_at + 8], "little") < chunk.chunk_length
    data[length_at:length_at + 8] = (2**36).to_bytes(8, "little")  # 64 GiB
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    d = read_day(bad, allow_truncated=True)
    assert d.truncated and 0 < len(d.scans) < 600
    assert d.scans.equals(read_day(day).scans.iloc[:len(d.scans)])


def test_unknown_signal(tmp_path: Path) -> None:
    path = tmp_path / "unknown.mcap"
    with DayWriter(path) as w:
        w.write(TOPIC_SCAN, T0, {"T_air_in": 450.0, "T_air_inlet": 451.0})
    with pytest.raises(IngestError, match=r"unknown\.mcap.*unknown signal 'T_air_inlet'"):
        read_day(path)
    with pytest.raises(IngestError, match="T_air_inlet"):
        list(iter_messages(path))


def test_non_numeric_signal(tmp_path: Path) -> None:
    path = tmp_path / "text.mcap"
    with DayWriter(path) as w:
        w.write(TOPIC_SCAN, T0, {"T_air_in": "hot"})
    with pytest.raises(IngestError, match="signal T_air_in has non-numeric value"):
        read_day(path)


def test_refused_lab_bodies_are_reported_and_skipped(tmp_path: Path, caplog) -> None:
    path = tmp_path / "lab.mcap"
    good = {"sample_time_ns": T0, "moisture_out": 0.1, "sample_id": "ok"}
    with DayWriter(path) as w:
        w.write(TOPIC_SCAN, T0, scan(0))
        w.write(TOPIC_LAB, T0 + 1, {"sample_time_ns": "yesterday", "moisture_out": 0.1,
                                    "sample_id": "a"})
        w.write(TOPIC_LAB, T0 + 2, {"sample_time_ns": T0, "moisture_out": None,
                                    "sample_id": "b"})
        w.write(TOPIC_LAB, T0 + 3, {"sample_time_ns": T0, "sample_id": "c"})
        w.write(TOPIC_LAB, T0 + 4, {"sample_time_ns": T0, "moisture_out": math.inf,
                                    "sample_id": "d"})  # written as null
        w.write(TOPIC_LAB, T0 + 5, good)
        w.write(TOPIC_SCAN, T0 + PERIOD, scan(1))
    with caplog.at_level("WARNING", logger="softsensor.recording.mcap_day"):
        d = read_day(path)
    # never NaN: only the good result is kept, and nothing else is lost
    assert list(d.labs["sample_id"]) == ["ok"] and d.labs["moisture_out"].iloc[0] == 0.1
    assert len(d.scans) == 2 and d.topic(TOPIC_LAB) == [(T0 + 5, good)]
    assert len(d.refused_labs) == 4
    for sid, why in zip("abcd", ["sample_time", "moisture_out None is not a number",
                                 "lacks moisture_out", "moisture_out None is not a number"],
                        strict=True):
        line = next(r for r in d.refused_labs if r.endswith(f"(sample_id {sid})"))
        assert why in line and line.startswith(f"{path}: {TOPIC_LAB} at ") and "\n" not in line
    assert "4 lab result(s) refused and skipped" in caplog.text
    # the streaming reader applies the same rule
    caplog.clear()
    with caplog.at_level("WARNING", logger="softsensor.recording.mcap_day"):
        got = [(topic, t) for topic, t, _ in iter_messages(path)]
    assert got == [(TOPIC_SCAN, T0), (TOPIC_LAB, T0 + 5), (TOPIC_SCAN, T0 + PERIOD)]
    assert caplog.text.count("lab result skipped") == 4
