"""What flows on the bus and in recorded days (``softsensor/messages.py``): the lab-result
contract and its one parser, scan bodies, the one JSON encoding."""

from __future__ import annotations

import json
import math

import pytest

from softsensor.errors import IngestError
from softsensor.messages import (
    LabResult,
    encode_body,
    lab_body,
    lab_from_body,
    make_lab_result,
    parse_sample_time,
    scan_values,
)
from softsensor.signals import SCAN_SIGNALS

T_S = 1_750_000_000  # 2025-06-15T15:06:40Z
T_NS = T_S * 10**9
NOW_NS = T_NS + 3600 * 10**9


def test_sample_time_forms() -> None:
    assert parse_sample_time(T_NS) == T_NS
    assert parse_sample_time(str(T_NS)) == T_NS
    assert parse_sample_time("2025-06-15T15:06:40Z") == T_NS
    assert parse_sample_time("2025-06-15T15:06:40") == T_NS
    assert parse_sample_time("2025-06-15 17:06:40.25+02:00") == T_NS + 250_000_000
    with pytest.raises(IngestError, match="neither ISO-8601 nor ns"):
        parse_sample_time("15.06.2025 15:06")


@pytest.mark.parametrize("moisture, match", [
    (-0.01, "outside the plausible range 0..2"),
    (2.5, "outside the plausible range"),
    (math.nan, "not finite"),
    (math.inf, "not finite"),
    ("0,105", "not a number"),
    (True, "not a number"),
    (None, "not a number"),
])
def test_bad_moisture(moisture: object, match: str) -> None:
    with pytest.raises(IngestError, match=match):
        make_lab_result(T_NS, moisture, "L1", where="x")


def test_bad_time_and_id() -> None:
    with pytest.raises(IngestError, match="before 2000"):
        make_lab_result(T_S, 0.1, "L1")  # seconds, not ns
    with pytest.raises(IngestError, match="after the result arrived"):
        make_lab_result(T_NS + 7200 * 10**9, 0.1, "L1", log_time_ns=T_NS)
    with pytest.raises(IngestError, match="sample_id is empty"):
        make_lab_result(T_NS, 0.1, "  ")
    lab = make_lab_result(T_NS, "0.105", 42, log_time_ns=NOW_NS)
    assert lab == LabResult(T_NS, 0.105, "42", NOW_NS)


def test_bus_body() -> None:
    body = {"sample_time_ns": T_NS, "moisture_out": 0.1, "sample_id": "L1", "time_ns": NOW_NS}
    lab = lab_from_body(body)
    assert lab == LabResult(T_NS, 0.1, "L1", NOW_NS)
    assert lab_body(lab) == {"sample_time_ns": T_NS, "moisture_out": 0.1, "sample_id": "L1"}
    with pytest.raises(IngestError, match="plant/dryer1/lab: lab entry lacks sample_time_ns"):
        lab_from_body({"moisture_out": 0.1, "sample_id": "x"}, where="plant/dryer1/lab")
    with pytest.raises(IngestError, match="plant/dryer1/lab: lab entry lacks moisture_out"):
        lab_from_body({"sample_time_ns": T_NS, "sample_id": "x"}, where="plant/dryer1/lab")
    with pytest.raises(IngestError, match="moisture_out None is not a number"):
        lab_from_body(dict(body, moisture_out=None))


def test_encode_body_is_strict_json() -> None:
    assert json.loads(encode_body({"a": math.nan, "b": {"c": -math.inf}})) == {
        "a": None, "b": {"c": None}}


def test_extra_fields_allowed() -> None:
    v = scan_values({"T_amb": 280, "time_ns": 1, "seq": 4, "plc_ts_ns": 3, "source": "modbus"})
    assert v["T_amb"] == 280.0 and math.isnan(v["m_air"]) and set(v) == set(SCAN_SIGNALS)
