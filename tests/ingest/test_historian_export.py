"""``softsensor import``: historian exports and LIMS files into a recorded day.

The oracle is the demo day itself: its scans, taken once a minute, are written out the way a
historian would (local time, plant units converted by hand here, not by pint) and must come
back as the same SI values at the same UTC times, also across a DST change.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from paths import REPLAY

from softsensor.cli import main as cli_main
from softsensor.recording.mcap_day import read_day
from softsensor.signals import SCAN_SIGNALS, TOPIC_LAB, TOPIC_SCAN

ZONE = "Europe/Stockholm"
MIN = 60 * 10**9

#: signal -> (column/tag, unit, SI -> plant unit by hand, decimals printed in the CSV)
PLANT: dict[str, tuple[str, str, object, int]] = {
    "T_air_in": ("TI101", "degC", lambda k: k - 273.15, 2),
    "m_air": ("FI102", "t/h", lambda q: q * 3.6, 3),
    "m_fiber": ("WI103", "t/h", lambda q: q * 3.6, 4),
    "T_fiber_in": ("TI104", "degC", lambda k: k - 273.15, 2),
    "m_steam": ("FI105", "kg/h", lambda q: q * 3600.0, 2),
    "T_amb": ("TI001", "degF", lambda k: k * 9 / 5 - 459.67, 2),
    "H_amb": ("MI002", "g/kg", lambda h: h * 1000.0, 4),
    "flap_cmd": ("TIC110.OP", "%", lambda p: p, 3),
    "T_sp": ("TIC110.SP", "K", lambda k: k, 2),
    "T_dryer_out": ("TIC110.PV", "degC", lambda k: k - 273.15, 2),
    "T_cyclone_out": ("TI111", "degC", lambda k: k - 273.15, 2),
}
#: Half the last printed digit, back in SI (the CSV's printed precision).
SI_STEP: dict[str, float] = {
    "T_air_in": 0.005, "m_air": 0.0005 / 3.6, "m_fiber": 0.00005 / 3.6, "T_fiber_in": 0.005,
    "m_steam": 0.005 / 3600, "T_amb": 0.005 * 5 / 9, "H_amb": 0.00005 / 1000,
    "flap_cmd": 0.0005, "T_sp": 0.005, "T_dryer_out": 0.005, "T_cyclone_out": 0.005,
}


@pytest.fixture(scope="module")
def minutes() -> pd.DataFrame:
    """Four hours of the demo day's scans, one per minute [SI]."""
    day = read_day(REPLAY / "demo-day.mcap", topics=[TOPIC_SCAN])
    s = day.scans
    s = s[(s.index - s.index[0]) % MIN == 0]
    return s.iloc[:240].reset_index(drop=True)


def wide_map(tmp_path: Path, *, zone: str | None = ZONE, extra: str = "",
             units: dict[str, str] | None = None) -> Path:
    units = units or {}
    text = ('[source]\nlayout = "wide"\ntime_column = "time"\n'
            + (f'time_zone = "{zone}"\n' if zone else "") + extra + "\n")
    for name, (col, unit, _f, _d) in PLANT.items():
        text += f'[signals.{name}]\ncolumn = "{col}"\nunit = "{units.get(name, unit)}"\n\n'
    path = tmp_path / "map.toml"
    path.write_text(text)
    return path


def run(capsys, *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = cli_main(["import", *args])
    got = capsys.readouterr()
    # the verb's summary is its one line on stderr; stdout stays empty (no JSON was asked)
    assert got.out == "", got.out
    return rc, got.err if rc == 0 else "", got.err


def local_text(utc_ns: np.ndarray) -> list[str]:
    """Naive local wall-clock strings of UTC times, as a historian prints them."""
    return list(pd.to_datetime(utc_ns, unit="ns", utc=True).tz_convert(ZONE)
                .strftime("%Y-%m-%d %H:%M:%S"))


BAD = {(10, "T_air_in"): "Bad", (11, "T_air_in"): "Bad", (50, "m_fiber"): "I/O Timeout",
       (200, "T_cyclone_out"): " shutdown "}


@pytest.mark.parametrize("start", ["2026-03-28T23:00:00Z", "2026-10-24T23:00:00Z"],
                         ids=["spring-forward", "fall-back"])
def test_wide_local_time_csv_round_trips_across_dst(minutes, tmp_path, capsys, start) -> None:
    t0 = pd.Timestamp(start).value
    utc = t0 + np.arange(len(minutes), dtype=np.int64) * MIN
    stamps = local_text(utc)
    # The export really crosses the change: an hour skipped (spring) or repeated (autumn).
    assert len(set(stamps)) == len(stamps) - (60 if "10-24" in start else 0)
    assert any(s.endswith("03:00:00") for s in stamps[:240])
    cols = {"time": stamps}
    for name, (col, _u, conv, dec) in PLANT.items():
        cols[col] = [BAD.get((i, name), f"{conv(v):.{dec}f}")
                     for i, v in enumerate(minutes[name])]
    pd.DataFrame(cols).to_csv(tmp_path / "export.csv", index=False)
    rc, out, err = run(capsys, "--map", str(wide_map(tmp_path)), "--scans",
                       str(tmp_path / "export.csv"), "--out", str(tmp_path / "day.mcap"))
    assert rc == 0, err
    assert "240 rows read, 240 scans" in out and "period 60 s (regular)" in out, out
    assert "bad values: T_air_in 2, m_fiber 1, T_cyclone_out 1; missing: none" in out, out
    day = read_day(tmp_path / "day.mcap")
    np.testing.assert_array_equal(day.scans.index.to_numpy(), utc)
    for name in SCAN_SIGNALS:
        got, want = day.scans[name].to_numpy(), minutes[name].to_numpy()
        bad = [i for (i, s) in BAD if s == name]
        assert np.isnan(got[bad]).all()
        keep = np.setdiff1d(np.arange(len(got)), bad)
        np.testing.assert_allclose(got[keep], want[keep], rtol=0,
                                   atol=SI_STEP[name] * 1.001, err_msg=name)


def test_long_layout_parquet_with_quality_gaps_and_irregular_times(minutes, tmp_path,
                                                                   capsys) -> None:
    n = len(minutes)
    jitter = (np.arange(n) % 7) * 10**9  # irregular: 60 s +- a few seconds
    utc = pd.Timestamp("2026-03-29T00:00:00Z").value + np.arange(n) * MIN + jitter
    keep = np.ones(n, bool)
    keep[100:110] = False  # a 10-minute gap in every tag
    naive_local = (pd.to_datetime(utc, unit="ns", utc=True).tz_convert(ZONE)
                   .tz_localize(None))
    rows = []
    for name, (tag, _unit, conv, _dec) in PLANT.items():
        for i in np.flatnonzero(keep):
            if name == "m_air" and i == 30:
                continue  # one tag absent at one time: missing, not bad
            quality = "Bad Quality" if (name == "T_sp" and i in (5, 6, 7)) else "Good"
            rows.append((naive_local[i], tag, float(conv(minutes[name][i])), quality))
    rows += [(naive_local[i], "OTHER.PV", 1.0, "Good") for i in range(5)]  # not in the map
    frame = pd.DataFrame(rows, columns=["ts", "tag", "val", "q"]).sample(frac=1, random_state=1)
    frame.to_parquet(tmp_path / "export.parquet", index=False)
    text = ('[source]\nlayout = "long"\ntime_column = "ts"\ntag_column = "tag"\n'
            f'value_column = "val"\nquality_column = "q"\ntime_zone = "{ZONE}"\n\n')
    for name, (tag, unit, _f, _d) in PLANT.items():
        text += f'[signals.{name}]\ntag = "{tag}"\nunit = "{unit}"\n\n'
    (tmp_path / "map.toml").write_text(text)
    rc, out, err = run(capsys, "--map", str(tmp_path / "map.toml"), "--scans",
                       str(tmp_path / "export.parquet"), "--out", str(tmp_path / "day.mcap"))
    assert rc == 0, err
    assert "5 rows of unmapped tags skipped" in out and "(irregular)" in out, out
    assert "bad values: T_sp 3; missing: m_air 1" in out, out
    day = read_day(tmp_path / "day.mcap")
    np.testing.assert_array_equal(day.scans.index.to_numpy(), utc[keep])
    for name in SCAN_SIGNALS:
        got = day.scans[name].to_numpy()
        want = minutes[name].to_numpy()[keep]
        nulls = {"T_sp": [5, 6, 7], "m_air": [30]}.get(name, [])
        assert np.isnan(got[nulls]).all()
        ok = np.setdiff1d(np.arange(len(got)), nulls)
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-12, atol=1e-9, err_msg=name)


def test_wet_basis_percent_labs_become_dry_basis_at_the_available_time(minutes, tmp_path,
                                                                       capsys) -> None:
    utc = pd.Timestamp("2026-06-01T08:00:00Z").value + np.arange(10) * MIN
    pd.DataFrame({"time": local_text(utc), **{col: [f"{conv(v):.4f}" for v in minutes[name][:10]]
                  for name, (col, _u, conv, _d) in PLANT.items()}}).to_csv(
        tmp_path / "export.csv", index=False)
    # Summer time in Stockholm is UTC+2: 10:03 local is 08:03 UTC.
    pd.DataFrame({"SampleTime": ["2026-06-01 10:03:00", "2026-06-01 10:05:30",
                                 "2026-06-01 10:07:00"],
                  "ID": ["A1", "A2", "A3"], "H2O": ["50", "9,0909", "Bad"]}).to_csv(
        tmp_path / "lims.csv", sep=";", index=False)
    hmap = wide_map(tmp_path).read_text() + (
        '[lab]\nsample_time_column = "SampleTime"\nmoisture_column = "H2O"\nunit = "%"\n'
        'basis = "wet"\nsample_id_column = "ID"\ndelay_min = 40\ndelimiter = ";"\n'
        'decimal = ","\n')
    (tmp_path / "map.toml").write_text(hmap)
    rc, out, err = run(capsys, "--map", str(tmp_path / "map.toml"), "--scans",
                       str(tmp_path / "export.csv"), "--lab", str(tmp_path / "lims.csv"),
                       "--out", str(tmp_path / "day.mcap"))
    assert rc == 0, err
    assert "2 labs written from 3 rows (1 without a result)" in out, out
    labs = read_day(tmp_path / "day.mcap").labs
    assert labs.sample_id.tolist() == ["A1", "A2"]
    np.testing.assert_allclose(labs.moisture_out, [1.0, 0.1], rtol=1e-4)
    sample = pd.to_datetime(["2026-06-01T08:03:00Z", "2026-06-01T08:05:30Z"]).as_unit("ns")
    np.testing.assert_array_equal(labs.sample_time_ns, sample.asi8)
    np.testing.assert_array_equal(labs.log_time_ns, sample.asi8 + 40 * MIN)


def test_shipped_example_imports_to_the_demo_days_values(tmp_path, capsys) -> None:
    rc, out, err = run(capsys, "--map", str(REPLAY / "historian-map.toml"), "--scans",
                       str(REPLAY / "historian-example.csv"), "--lab",
                       str(REPLAY / "lims-example.csv"), "--out", str(tmp_path / "day.mcap"))
    assert rc == 0, err
    got = read_day(tmp_path / "day.mcap")
    demo = read_day(REPLAY / "demo-day.mcap", topics=[TOPIC_SCAN, TOPIC_LAB])
    want = demo.scans.loc[got.scans.index]
    assert len(got.scans) == 720 and int(got.scans.isna().sum().sum()) == 5
    diff = (got.scans - want).abs().max()
    assert diff["T_dryer_out"] <= 0.005 + 1e-9 and diff["m_air"] <= 0.0005 / 3.6 + 1e-12, diff
    labs = demo.labs.iloc[:len(got.labs)]
    assert len(got.labs) == 4 and got.labs.sample_id.tolist() == labs.sample_id.tolist()
    np.testing.assert_allclose(got.labs.moisture_out, labs.moisture_out, atol=2e-5)
    assert np.abs(got.labs.sample_time_ns - labs.sample_time_ns).max() < 10**9


def _err(capsys, tmp_path: Path, map_path: Path, csv_text: str) -> str:
    (tmp_path / "export.csv").write_text(csv_text)
    rc, out, err = run(capsys, "--map", str(map_path), "--scans", str(tmp_path / "export.csv"),
                       "--out", str(tmp_path / "day.mcap"))
    assert rc == 2 and out == "", (rc, out, err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


#: A plausible value of every column of PLANT, in its plant unit.
NOMINAL = {"TI101": "200", "FI102": "295", "WI103": "21.6", "TI104": "97", "FI105": "1800",
           "TI001": "50", "MI002": "8", "TIC110.OP": "40", "TIC110.SP": "348",
           "TIC110.PV": "75", "TI111": "72"}


def _csv(times: list[str], value: str | None = None) -> str:
    header = "time," + ",".join(col for col, *_ in PLANT.values())
    row = ",".join(value or NOMINAL[col] for col, *_ in PLANT.values())
    return header + "\n" + "\n".join(f"{t},{row}" for t in times) + "\n"


def test_naive_times_without_a_zone_are_refused(tmp_path, capsys) -> None:
    err = _err(capsys, tmp_path, wide_map(tmp_path, zone=None), _csv(["2026-01-05 10:00:00"]))
    assert "no zone" in err and "source.time_zone" in err, err
    # The same times with an offset need no zone.
    rc, out, _ = run(capsys, "--map", str(tmp_path / "map.toml"), "--scans",
                     str(_write(tmp_path, _csv(["2026-01-05T10:00:00+01:00"]))), "--out",
                     str(tmp_path / "ok.mcap"))
    assert rc == 0 and "2026-01-05T09:00:00Z" in out, out


def _write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "offset.csv").write_text(text)
    return tmp_path / "offset.csv"


def test_unknown_unit_is_refused_naming_the_key(tmp_path, capsys) -> None:
    err = _err(capsys, tmp_path, wide_map(tmp_path, units={"T_air_in": "degX"}),
               _csv(["2026-01-05 10:00:00"]))
    assert "map.toml: signals.T_air_in.unit 'degX' is not a unit" in err, err
    err = _err(capsys, tmp_path, wide_map(tmp_path, units={"m_air": "degC"}),
               _csv(["2026-01-05 10:00:00"]))
    assert "signals.m_air.unit 'degC' cannot be converted to kg/s" in err, err


def test_missing_column_is_refused_naming_it(tmp_path, capsys) -> None:
    text = _csv(["2026-01-05 10:00:00"]).replace("FI102", "FI-102")
    err = _err(capsys, tmp_path, wide_map(tmp_path), text)
    assert "column 'FI102' of signals.m_air.column is not in the file" in err, err


def test_timestamp_unit_mistake_is_refused_with_a_hint(tmp_path, capsys) -> None:
    seconds = str(pd.Timestamp("2026-01-05T10:00:00Z").value // 10**9)
    err = _err(capsys, tmp_path, wide_map(tmp_path, extra='time_unit = "ms"\n'),
               _csv([seconds]))
    assert "gives 1970-01-" in err and "before 2000" in err, err
    assert "source.time_unit = 'ms'" in err and "as s it would be 2026-01-05T10:00:00Z" in err
    nanoseconds = str(pd.Timestamp("2026-01-05T10:00:00Z").value)
    err = _err(capsys, tmp_path, wide_map(tmp_path, extra='time_unit = "s"\n'),
               _csv([nanoseconds]))
    assert "more than a day in the future" in err, err
    assert "as ns it would be 2026-01-05T10:00:00Z" in err, err


def test_text_that_is_neither_number_nor_bad_string_is_refused(tmp_path, capsys) -> None:
    err = _err(capsys, tmp_path, wide_map(tmp_path),
               _csv(["2026-01-05 10:00:00"], value="12.5 degC"))
    assert "row 1: TI101 value '12.5 degC'" in err and "source.bad_values" in err, err
    # Declared in the map, the same string is a bad value.
    rc, out, err = run(capsys, "--map", str(wide_map(tmp_path,
                                                     extra='bad_values = ["12.5 degC"]\n')),
                       "--scans", str(tmp_path / "export.csv"), "--out",
                       str(tmp_path / "ok.mcap"))
    assert rc == 0 and "bad values: T_air_in 1, m_air 1" in out, (out, err)
    assert math.isnan(read_day(tmp_path / "ok.mcap").scans["T_air_in"].iloc[0])


def test_map_errors_name_the_file_and_dotted_key(tmp_path, capsys) -> None:
    path = wide_map(tmp_path)
    path.write_text(path.read_text().replace('layout = "wide"', 'layout = "tall"'))
    err = _err(capsys, tmp_path, path, _csv(["2026-01-05 10:00:00"]))
    assert re.search(r"map\.toml: source\.layout must be 'wide' or 'long', got 'tall'", err)
    path.write_text(wide_map(tmp_path).read_text() + '[signals.T_foo]\ncolumn = "x"\n'
                    'unit = "K"\n')
    err = _err(capsys, tmp_path, path, _csv(["2026-01-05 10:00:00"]))
    assert "map.toml: signals.T_foo is not a scan signal" in err, err
