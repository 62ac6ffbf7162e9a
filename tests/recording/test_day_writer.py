"""Writing recorded days: the MCAP layout any tool reads, strict JSON, chunks that reach the
disk, errors that name the file."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from recorded_days import PERIOD, T0, scan

from softsensor.errors import IngestError
from softsensor.recording.day_writer import DayWriter
from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_HEALTH, TOPIC_LAB, TOPIC_SCAN


def test_nan_and_null(tmp_path: Path) -> None:
    path = tmp_path / "nan.mcap"
    with DayWriter(path) as w:
        w.write(TOPIC_SCAN, T0, {"T_air_in": math.nan, "m_air": None, "T_amb": np.float64(280.0)})
        w.write(TOPIC_ESTIMATE, T0, {"moisture_out": float("inf"), "x": [1.0, math.nan],
                                     "n": np.int64(3), "lab_updated": np.bool_(True)})
    d = read_day(path)
    row = d.scans.iloc[0]
    assert math.isnan(row["T_air_in"]) and math.isnan(row["m_air"])
    assert math.isnan(row["T_dryer_out"])  # missing key
    assert row["T_amb"] == 280.0
    (_, est), = d.topic(TOPIC_ESTIMATE)
    assert est == {"moisture_out": None, "x": [1.0, None], "n": 3, "lab_updated": True}
    # the raw bytes are strict JSON: null, never NaN
    with open(path, "rb") as f:
        raw = [m.data for _, _, m in make_reader(f).iter_messages()]
    assert b"NaN" not in b"".join(raw) and b"null" in raw[0]


def test_plain_mcap_reader_sees_jsonschema_and_json(day: Path) -> None:
    with open(day, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 600
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        assert len(summary.chunk_indexes) > 5  # small chunks
        topics = set()
        for schema, channel, msg in reader.iter_messages():
            assert schema is not None and schema.encoding == "jsonschema"
            assert channel.message_encoding == "json"
            assert json.loads(schema.data)["type"] == "object"
            json.loads(msg.data)
            topics.add(channel.topic)
    assert topics == {TOPIC_SCAN, TOPIC_LAB, TOPIC_HEALTH, "/truth/plant"}


def test_writer_flush_makes_data_readable_before_close(tmp_path: Path) -> None:
    path = tmp_path / "open.mcap"
    w = DayWriter(path)
    try:
        for i in range(10):
            w.write(TOPIC_SCAN, T0 + i * PERIOD, scan(i))
        w.flush()
        d = read_day(path, allow_truncated=True)
        assert d.truncated and len(d.scans) == 10
    finally:
        w.close()
    assert not read_day(path).truncated
    w.close()  # idempotent
    with pytest.raises(ValueError):
        w.write(TOPIC_SCAN, T0, {})


def test_write_error_names_file(tmp_path: Path) -> None:
    with pytest.raises(IngestError, match="nodir"):
        DayWriter(tmp_path / "nodir" / "x.mcap")
