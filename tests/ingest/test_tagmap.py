"""Tag map loading, validation (one-line errors naming the key) and read grouping."""

import re
from pathlib import Path

import pytest

from softsensor.errors import ConfigError
from softsensor.ingest.registers import DATA_TYPES
from softsensor.ingest.tagmap import (
    DEFAULT_TAGMAP,
    MAX_READ_REGISTERS,
    group_reads,
    load_tagmap,
    parse_tagmap,
)
from softsensor.signals import SCAN_SIGNALS

MINIMAL = """\
[modbus]
host = "127.0.0.1"
port = 502

[tags.T_air_in]
unit_id = 1
table = "input"
address = 0
type = "float32"
unit = "degC"
valid_min = 300.0
valid_max = 700.0
"""


def _load(tmp_path: Path, text: str):
    path = tmp_path / "tagmap.toml"
    path.write_text(text)
    return load_tagmap(path), str(path)


def _error(tmp_path: Path, text: str) -> str:
    path = tmp_path / "tagmap.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_tagmap(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: ")
    return msg


def test_default_tagmap_covers_every_scan_signal_type_and_order():
    tm = load_tagmap()
    assert tm.source == str(DEFAULT_TAGMAP)
    assert set(tm.signals) == set(SCAN_SIGNALS)
    assert tm.modbus.poll_period_s == 10.0
    assert {t.data_type for t in tm.tags} == set(DATA_TYPES)
    orders = {(t.word_order, t.byte_order) for t in tm.tags if t.count > 1}
    assert orders == {("big", "big"), ("little", "big"), ("big", "little"), ("little", "little")}
    assert {t.table for t in tm.tags} == {"holding", "input"}
    for t in tm.tags:
        assert t.si_unit == SCAN_SIGNALS[t.signal]
    assert tm.tag("T_sp").frozen_after_s == 0  # set points legitimately stay constant


def test_default_tagmap_reads_in_three_requests():
    reqs = group_reads(load_tagmap())
    got = [(r.unit_id, r.table, r.address, r.count, [t.signal for t in r.tags]) for r in reqs]
    assert got == [
        (1, "holding", 100, 5, ["m_air", "m_fiber", "m_steam", "flap_cmd"]),
        (1, "input", 0, 14, ["T_air_in", "T_dryer_out", "T_cyclone_out", "T_fiber_in", "T_sp"]),
        (2, "input", 0, 4, ["T_amb", "H_amb"]),
    ]
    assert [r.function_code for r in reqs] == [3, 4, 4]


def test_minimal_tagmap_takes_defaults(tmp_path):
    tm, _ = _load(tmp_path, MINIMAL)
    t = tm.tag("T_air_in")
    assert (t.word_order, t.byte_order, t.scale, t.offset, t.frozen_after_s) == (
        "big", "big", 1.0, 0.0, None)
    assert tm.modbus.timeout_s == 1.0 and tm.modbus.max_registers_per_read == 125
    assert tm.with_endpoint("localhost", 1502).modbus.port == 1502


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("address = 0", "address = -3",
     "tags.T_air_in.address must be >= 0, got -3"),
    ("address = 0", "address = 65535",
     "tags.T_air_in.address leaves no room for 2 registers of float32, got 65535"),
    ('type = "float32"', 'type = "float16"',
     "tags.T_air_in.type must be one of int16, uint16, int32, uint32, float32, float64, "
     "got 'float16'"),
    ("[tags.T_air_in]", "[tags.T_air_inn]", "tags.T_air_inn is not a scan signal (known: "),
    ("unit_id = 1", "unit_id = 1\ncolour = 3",
     "tags.T_air_in.colour is not a known key (known: "),
    ("port = 502", "port = 502\npoll_every = 3", "modbus.poll_every is not a known key"),
    ("address = 0\n", "", "tags.T_air_in.address is missing"),
    ('host = "127.0.0.1"\n', "", "modbus.host is missing"),
    ("port = 502", "port = 502\nmax_registers_per_read = 200",
     "modbus.max_registers_per_read must be <= 125, got 200"),
    ('unit = "degC"', 'unit = "kg/s"', "tags.T_air_in.unit must convert to K (one of K, degC, "
     "degF), got 'kg/s'"),
    ('unit = "degC"', 'unit = "furlong"', "tags.T_air_in.unit must be one of "),
    ('table = "input"', 'table = "coil"',
     "tags.T_air_in.table must be one of holding, input, got 'coil'"),
    ("valid_max = 700.0", "valid_max = 200.0",
     "tags.T_air_in.valid_max must be > valid_min (300), got 200"),
    ("unit_id = 1", "unit_id = true", "tags.T_air_in.unit_id must be an integer, got True"),
    ("unit_id = 1", 'unit_id = 1\nscale = 0', "tags.T_air_in.scale must not be 0"),
    ("unit_id = 1", 'unit_id = 1\nscale = nan', "tags.T_air_in.scale must be finite, got nan"),
    ("port = 502", "port = 502\npoll_period_s = 0", "modbus.poll_period_s must be > 0, got 0"),
    ("port = 502", "port = 502\nreconnect_delay_max_s = 0.1",
     "modbus.reconnect_delay_max_s must be >= reconnect_delay_s (1), got 0.1"),
    ("port = 502", "port = 70000", "modbus.port must be <= 65535, got 70000"),
    ("[modbus]", "[modbuss]", "modbuss is not a known section (known: modbus, tags, clock)"),
    ("unit_id = 1", 'unit_id = 1\nword_order = "middle"',
     "tags.T_air_in.word_order must be one of big, little, got 'middle'"),
    ("unit_id = 1", "unit_id = 256", "tags.T_air_in.unit_id must be <= 255, got 256"),
    ("unit_id = 1", "unit_id = 1.0", "tags.T_air_in.unit_id must be an integer, got 1.0"),
    ('type = "float32"', "type = 4", "tags.T_air_in.type must be one of int16, "),
    ("valid_min = 300.0", 'valid_min = "low"',
     "tags.T_air_in.valid_min must be a number, got 'low'"),
    ("unit_id = 1", "unit_id = 1\nfrozen_after_s = -1",
     "tags.T_air_in.frozen_after_s must be >= 0, got -1"),
    ('host = "127.0.0.1"', 'host = ""', "modbus.host must be a non-empty string, got ''"),
    ("[tags.T_air_in]", "[tags]\nT_air_in = 3\n[tags.T_sp]",
     "[tags.T_air_in] must be a table, got int"),
])
def test_bad_tagmaps_name_the_key(tmp_path, old, new, expected):
    assert old in MINIMAL
    text = MINIMAL.replace(old, new, 1)
    msg = _error(tmp_path, text)
    assert expected in msg, msg


def test_overlapping_tags_are_rejected(tmp_path):
    text = MINIMAL + """
[tags.T_dryer_out]
unit_id = 1
table = "input"
address = 1
type = "float32"
unit = "degC"
valid_min = 280.0
valid_max = 450.0
"""
    msg = _error(tmp_path, text)
    assert "tags.T_dryer_out.address 1 overlaps tags.T_air_in (unit 1 input registers 0..1)" in msg
    # the same address in the other table is fine
    other = text.replace('table = "input"\naddress = 1', 'table = "holding"\naddress = 1')
    assert other != text
    tm, _ = _load(tmp_path, other)
    assert len(tm.tags) == 2


def test_missing_and_malformed_files(tmp_path):
    missing = re.escape(f"{tmp_path / 'nope.toml'}: no such config file")
    with pytest.raises(ConfigError, match=missing):
        load_tagmap(tmp_path / "nope.toml")
    msg = _error(tmp_path, "[modbus\nhost=1")
    assert "malformed TOML" in msg


def _tag(signal, address, dtype="float32", unit_id=1, table="input"):
    unit = {"K": "K", "kg/s": "kg/s", "kg/kg": "kg/kg", "%": "%"}[SCAN_SIGNALS[signal]]
    return {"unit_id": unit_id, "table": table, "address": address, "type": dtype,
            "unit": unit, "valid_min": 0.0, "valid_max": 1000.0}


def _map(tags, **modbus):
    return parse_tagmap({"modbus": {"host": "h", "port": 1, **modbus}, "tags": tags}, "test")


def test_grouping_bridges_small_gaps_only():
    tags = {"T_air_in": _tag("T_air_in", 0), "T_dryer_out": _tag("T_dryer_out", 6),
            "T_cyclone_out": _tag("T_cyclone_out", 13)}
    reqs = group_reads(_map(tags, max_gap_registers=4))
    assert [(r.address, r.count) for r in reqs] == [(0, 8), (13, 2)]  # gap 4 bridged, 5 not
    assert [(r.address, r.count) for r in group_reads(_map(tags, max_gap_registers=0))] == [
        (0, 2), (6, 2), (13, 2)]
    assert [(r.address, r.count) for r in group_reads(_map(tags, max_gap_registers=5))] == [
        (0, 15)]
    req = group_reads(_map(tags, max_gap_registers=5))[0]
    assert req.slice(req.tags[2]) == slice(13, 15)


def test_grouping_respects_the_125_register_limit_and_tables_and_units():
    tags = {"T_air_in": _tag("T_air_in", 0), "T_sp": _tag("T_sp", 121, "float64"),
            "T_amb": _tag("T_amb", 200, "float64")}
    reqs = group_reads(_map(tags, max_gap_registers=125))
    assert [(r.address, r.count) for r in reqs] == [(0, 125), (200, 4)]
    assert all(r.count <= MAX_READ_REGISTERS for r in reqs)
    tags["T_sp"] = _tag("T_sp", 122, "float64")  # 0..125 would be 126 registers
    assert [(r.address, r.count) for r in group_reads(_map(tags, max_gap_registers=125))] == [
        (0, 2), (122, 82)]
    assert [r.count for r in group_reads(_map(tags, max_gap_registers=125,
                                              max_registers_per_read=10))] == [2, 4, 4]
    tags = {"T_air_in": _tag("T_air_in", 0), "T_sp": _tag("T_sp", 2, table="holding"),
            "T_amb": _tag("T_amb", 2, unit_id=2)}
    reqs = group_reads(_map(tags))
    assert [(r.unit_id, r.table, r.address) for r in reqs] == [
        (1, "holding", 2), (1, "input", 0), (2, "input", 2)]
