"""Lab files (CSV and JSON) read as untrusted input: layout, refusal reasons, the plant's
clock."""

from __future__ import annotations

import json

import pytest

from softsensor.errors import IngestError
from softsensor.ingest.lab_files import parse_lab_csv, parse_lab_file, parse_lab_json

T_S = 1_750_000_000  # 2025-06-15T15:06:40Z
T_NS = T_S * 10**9
NOW_NS = T_NS + 3600 * 10**9


def test_csv_parsing() -> None:
    text = ("\ufeffsample_time,moisture_out,sample_id,operator\n"
            "2025-06-15T15:06:40Z,0.101,A1,jo\n"
            "\n"
            "2025-06-15T15:06:41Z,0.102,A2,jo\n")
    parsed = parse_lab_csv(text, log_time_ns=NOW_NS, where="day.csv")
    assert [r.sample_id for r in parsed.results] == ["A1", "A2"]
    assert parsed.results[1].sample_time_ns == T_NS + 10**9
    assert all(r.log_time_ns == NOW_NS for r in parsed.results)
    ns = parse_lab_csv(f"sample_time_ns,moisture_out,sample_id\n{T_NS},0.1,N1\n")
    assert ns.results[0].sample_time_ns == T_NS
    # one bad entry refuses the file, naming the row and the column, quoting none of it
    for body, match in [
        ("2025-06-15T16:00:00Z,abc,A3,jo\n", r"day.csv row 2: moisture_out value is neither"),
        ("2025-06-15T16:00:00Z,0.1,A4\n", r"day.csv line 3: 3 fields, the header has 4"),
        ("2025-06-15T16:00:00Z,5,A5,jo\n", r"row 2: moisture_out read as kg/kg on a dry basis "
                                           r"is outside"),
        ("2025-06-15T16:00:00Z,0,A6,jo\n", r"row 2: moisture_out is 0: a bone-dry sample"),
        ("15.06.2025 16:00Z,0.1,A7,jo\n", r"row 2: sample_time is not a time in format"),
    ]:
        bad = text.splitlines(keepends=True)[:2] + [body]
        with pytest.raises(IngestError, match=match) as info:
            parse_lab_csv("".join(bad), log_time_ns=NOW_NS, where="day.csv")
        assert not any(cell in str(info.value) for cell in ("abc", "A4", "A5", "A6", "15.06")), \
            info.value
    with pytest.raises(IngestError, match=r"x.csv: column 'sample_time' of "
                                          r"lab.sample_time_column is not in the file$"):
        parse_lab_csv("time,value\n1,2\n", where="x.csv")
    with pytest.raises(IngestError, match="no lab results after the header"):
        parse_lab_csv("sample_time,moisture_out,sample_id\n", where="x.csv")


def test_json_parsing() -> None:
    one = json.dumps({"sample_time": "2025-06-15T15:06:40Z", "moisture_out": 0.1,
                      "sample_id": "J1"})
    assert parse_lab_json(one).results[0].sample_time_ns == T_NS
    many = [{"sample_time_ns": T_NS, "moisture_out": 0.1, "sample_id": "J2"},
            {"sample_time_ns": T_NS + 1, "moisture_out": 0.12, "sample_id": "J3"}]
    assert [r.sample_id for r in parse_lab_json(json.dumps(many)).results] == ["J2", "J3"]
    for extra, match in [
        ({"sample_time_ns": T_NS, "moisture_out": 3.0, "sample_id": "J4"},
         r"m.json row 3: moisture_out read as kg/kg on a dry basis is outside the plausible "
         r"range 0..2 kg/kg dry basis \(set lab.unit"),
        ("junk", r"m.json entry 2: a JSON str, not an object"),
        ({"sample_time_ns": T_NS, "moisture_out": [1], "sample_id": "J5"},
         r"m.json entry 2: values must be numbers or text"),
    ]:
        with pytest.raises(IngestError, match=match):
            parse_lab_json(json.dumps([*many, extra]), where="m.json")
    with pytest.raises(IngestError, match="m.json: not valid JSON"):
        parse_lab_json("{", where="m.json")
    with pytest.raises(IngestError, match="not an object or a list"):
        parse_lab_json("5", where="m.json")


def test_naive_times_in_lab_files_are_on_the_plant_clock(tmp_path):
    """A LIMS writing local time without an offset: with the zone set, the sample lands at
    the right UTC instant (winter, +01:00), an explicit offset is kept, and without a zone the
    old reading (UTC) stays."""
    from zoneinfo import ZoneInfo

    f = tmp_path / "lims.csv"
    f.write_text("sample_time,moisture_out,sample_id\n2026-01-05 10:00:00,0.1,A\n")
    g = tmp_path / "lims-utc.csv"
    g.write_text("sample_time,moisture_out,sample_id\n2026-01-05T10:00:00+00:00,0.1,B\n")
    local = parse_lab_file(f, zone=ZoneInfo("Europe/Stockholm")).results
    local += parse_lab_file(g, zone=ZoneInfo("Europe/Stockholm")).results
    utc = parse_lab_file(f).results + parse_lab_file(g).results
    t_utc10 = 1_767_607_200 * 10**9  # 2026-01-05T10:00Z
    assert local[0].sample_time_ns == t_utc10 - 3600 * 10**9
    assert local[1].sample_time_ns == utc[1].sample_time_ns == t_utc10
    assert utc[0].sample_time_ns == t_utc10
