"""A plant engineer's own export (issue 24, item 1): relative humidity and dew point, physical
ranges named by tag, ``import --preview``, the CSV options plants need, the map's keys in
``docs/``, and exports bounded before they are read (issue 25, item 8).

The export is the shipped example (``replay/historian-example.csv``): an OSIsoft PI style CSV
for a Spanish plant, as ``replay/make_historian_example.py`` writes it from the demo day
(relative humidity by psychrolib, an outside reference), so its truth is known.
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import psychrolib
import pytest
from paths import REPLAY, REPO

from softsensor.cli import main as cli_main
from softsensor.ingest.historian_map import LabMap, SignalMap, SourceMap
from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_SCAN

MAP = (REPLAY / "historian-map.toml").read_text()
EXPORT = (REPLAY / "historian-example.csv").read_text(encoding="utf-8")
psychrolib.SetUnitSystem(psychrolib.SI)


def run(capsys, *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = cli_main(["import", *args])
    got = capsys.readouterr()
    return rc, got.out, got.err


def _files(tmp_path: Path, map_text: str = MAP, export: str = EXPORT) -> tuple[Path, Path]:
    (tmp_path / "map.toml").write_text(map_text)
    (tmp_path / "export.csv").write_text(export, encoding="utf-8")
    return tmp_path / "map.toml", tmp_path / "export.csv"


def _one_line_error(rc: int, err: str) -> str:
    assert rc == 2 and err.count("\n") == 1 and err.startswith("softsensor: "), (rc, err)
    return err


def test_the_plant_export_imports_with_humidity_from_relative_humidity(tmp_path, capsys):
    mp, ex = _files(tmp_path)
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    assert rc == 0, err
    # the summary speaks the plant's clock (Madrid, +01:00 in January)
    assert "720 scans 2026-01-05T01:00:00+01:00 .. 2026-01-05T12:59:00+01:00" in err, err
    assert "bad values: T_air_in 2, m_fiber 1, H_amb 1, T_cyclone_out 1" in err, err
    got = read_day(tmp_path / "day.mcap").scans
    want = read_day(REPLAY / "demo-day.mcap", topics=[TOPIC_SCAN]).scans.loc[got.index]
    ok = got.H_amb.notna()
    assert ok.sum() == 719
    # psychrolib wrote RH to 0.01 % beside T_amb to 0.01 °C (the saturation pressure moves
    # 6.5 %/K: 3e-4); the model's psychrometrics read them back
    np.testing.assert_allclose(got.H_amb[ok], want.H_amb[ok], rtol=5e-4)
    assert (got.T_dryer_out - want.T_dryer_out).abs().max() <= 0.005 + 1e-9


def test_a_relative_humidity_read_as_a_ratio_is_refused_naming_the_tag(tmp_path, capsys):
    """The issue's import wrote H_amb = 0.907 kg/kg and replay went on to NaN estimates."""
    mp, ex = _files(tmp_path, MAP.replace('quantity = "relative_humidity"', ""))
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    err = _one_line_error(rc, err)
    assert "MI-4702.PV (signals.H_amb) at 2026-01-05T00:00:00Z: 84.57 % is 0.8457 kg/kg, " \
           "outside the physical range 0..0.05 kg/kg of H_amb" in err, err
    assert "signals.H_amb.quantity = 'relative_humidity'" in err
    assert not (tmp_path / "day.mcap").exists()


@pytest.mark.parametrize("signal, tag, wrong, what, n_bad", [
    ("m_fiber", "WI-4713.PV", "kg/s", "21.1925 kg/s is 21.19 kg/s, outside the physical "
                                      "range -0.5..20 kg/s of m_fiber (and 468 more values)",
     1 + 469),
    ("T_dryer_out", "TIC-4720.PV", "K", "75.37 K is 75.37 K, outside the physical range "
                                        "230..500 K of T_dryer_out (and 719 more values)", 720),
])
def test_every_signal_is_checked_against_its_physical_range(tmp_path, capsys, signal, tag,
                                                            wrong, what, n_bad):
    text = re.sub(rf'(column = "{re.escape(tag)}"\nunit = )"[^"]+"', rf'\1"{wrong}"', MAP)
    assert text != MAP
    mp, ex = _files(tmp_path, text)
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    err = _one_line_error(rc, err)
    assert f"{tag} (signals.{signal})" in err and what in err, err
    assert f"is signals.{signal}.unit right?" in err
    # out_of_range = "null": the values are dropped and counted instead
    nulled = text.replace(f'column = "{tag}"', f'column = "{tag}"\nout_of_range = "null"')
    mp, ex = _files(tmp_path, nulled)
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    if signal == "m_fiber":
        # the values left inside the physical range (t/h read as kg/s: 18.5 kg/s) are still
        # outside what the estimator accepts: the envelope (issue 30) refuses them, naming t/h
        err = _one_line_error(rc, err)
        assert "outside the operating envelope 2..10 kg/s" in err and \
            "set signals.m_fiber.unit = 't/h'" in err, err
        return
    assert rc == 0 and f"{signal} {n_bad}," in err, err


def test_a_dew_point_column_becomes_a_humidity_ratio(tmp_path, capsys):
    frame = pd.read_csv(REPLAY / "historian-example.csv", dtype=str, keep_default_na=False)
    data = frame.iloc[1:].reset_index(drop=True)
    t_amb = pd.to_numeric(data["TI-4701.PV"])
    rh = pd.to_numeric(data["MI-4702.PV"], errors="coerce").fillna(50.0) / 100.0
    dew = [psychrolib.GetTDewPointFromRelHum(t, r) for t, r in zip(t_amb, rh, strict=True)]
    data["MI-4702.PV"] = [f"{d * 9 / 5 + 32:.3f}" for d in dew]  # in °F, for a second unit
    text = MAP.replace('unit = "%"\nquantity = "relative_humidity"',
                       'unit = "degF"\nquantity = "dew_point"')
    mp, ex = _files(tmp_path, text.replace("skip_rows = 1 ", "skip_rows = 0 "),
                    data.to_csv(index=False))
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    assert rc == 0, err
    got = read_day(tmp_path / "day.mcap").scans.H_amb.to_numpy()
    want = [psychrolib.GetHumRatioFromTDewPoint(d, 101_325.0) for d in dew]
    np.testing.assert_allclose(got, want, rtol=2e-4)


def test_preview_shows_ranges_units_and_first_rows_and_writes_nothing(tmp_path, capsys):
    mp, ex = _files(tmp_path, MAP.replace('quantity = "relative_humidity"', ""))
    rc, out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--preview", "3")
    assert rc == 0 and err.strip() == "import --preview: 720 scans read; nothing written", err
    lines = out.splitlines()
    assert lines[0].startswith("preview of ") and "2026-01-05T01:00:00+01:00" in lines[0]
    row = next(ln.split() for ln in lines if ln.startswith("m_air "))
    assert row[:9] == ["m_air", "FI-4712.PV", "t/h", "274.2", "315.4", "kg/s", "76.16",
                       "87.61", "-2..200"], row
    # the relative humidity read as a ratio is shown, not fatal, in the preview
    assert any(ln.startswith("OUTSIDE: ") and "MI-4702.PV (signals.H_amb)" in ln
               for ln in lines), out
    first = lines.index("first 3 scans (SI units, time UTC):")
    assert lines[first + 1].split()[:3] == ["time_utc", "T_air_in", "m_air"]
    assert lines[first + 2].split()[:3] == ["2026-01-05T00:00:00Z", "483", "84.0883"]
    assert len(lines) == first + 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["export.csv", "map.toml"]


def test_a_units_row_is_named_when_skip_rows_is_missing(tmp_path, capsys):
    mp, ex = _files(tmp_path, MAP.replace("skip_rows = 1 ", "skip_rows = 0 "))
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    err = _one_line_error(rc, err)
    assert "row 1:" in err and "set source.skip_rows = 1" in err, err


def test_day_first_dates_decimal_commas_and_thousands(tmp_path, capsys):
    """A semicolon CSV with decimal commas, thousands points and day-first dates that would
    be a valid but wrong date read month first (13/01 and 05/01)."""
    rows = [("13/01/2026 10:00:00", "1.811,92"), ("13/01/2026 10:01:00", "1.799,16")]
    text = "Zeit;FI-4715.PV\n" + "".join(f"{t};{v}\n" for t, v in rows)
    map_text = ('[source]\nlayout = "wide"\ntime_column = "Zeit"\ntime_zone = "Europe/Berlin"\n'
                'dayfirst = true\ndelimiter = ";"\ndecimal = ","\nthousands = "."\n\n'
                '[signals.m_steam]\ncolumn = "FI-4715.PV"\nunit = "kg/h"\n')
    mp, ex = _files(tmp_path, map_text, text)
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    assert rc == 0, err
    got = read_day(tmp_path / "day.mcap").scans
    assert got.index[0] == pd.Timestamp("2026-01-13T09:00:00Z").value
    np.testing.assert_allclose(got.m_steam, [1811.92 / 3600, 1799.16 / 3600])
    # the same dates without dayfirst are refused with the hint
    mp, ex = _files(tmp_path, map_text.replace("dayfirst = true\n", ""), text)
    rc, _out, err = run(capsys, "--map", str(mp), "--scans", str(ex), "--out",
                        str(tmp_path / "day.mcap"))
    assert "dayfirst = true" in _one_line_error(rc, err), err


def test_every_key_of_the_map_is_documented_in_docs():
    doc = (REPO / "docs" / "historian-map.md").read_text()
    documented = set(re.findall(r"`([a-z_]+)`", doc))
    for cls in (SourceMap, SignalMap, LabMap):
        missing = [f.name for f in dataclasses.fields(cls) if f.name not in documented]
        assert not missing, (cls.__name__, missing)


_MEASURED = """
import resource, sys
from softsensor.cli import main
try:
    rc = main(sys.argv[1:])
finally:
    sys.stderr.write(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}\\n")
sys.exit(rc)
"""


def _import_rss(*args: str) -> tuple[int, str, float]:
    """``softsensor import`` in a child; its exit status, stderr and its own peak RSS [MB]."""
    r = subprocess.run([sys.executable, "-c", _MEASURED, "import", *args],
                       capture_output=True, text=True, timeout=120)
    err, _, rss = r.stderr.rpartition("peak RSS ")
    return r.returncode, err, int(rss) / 1024


def test_huge_exports_are_refused_before_they_are_read(tmp_path):
    """Issue 25 item 8: a 170 kB Parquet of 3 million rows took 1.2 GB and a 50 MB one-line
    CSV 936 MB. Both are now refused from their footer or a streamed scan, in one line."""
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    mp, _ = _files(tmp_path)
    n = 3_000_000
    table = pa.table({"Timestamp": pa.array(np.full(n, 1_767_571_200, dtype=np.int64)),
                      "TI-4711.PV": pa.array(np.zeros(n))})
    pq.write_table(table, tmp_path / "big.parquet", compression="zstd")
    assert (tmp_path / "big.parquet").stat().st_size < 200_000
    rc, err, rss = _import_rss("--map", str(mp), "--scans", str(tmp_path / "big.parquet"),
                               "--out", str(tmp_path / "a.mcap"))
    assert rc == 2 and err.strip().splitlines() == [
        f"softsensor: {tmp_path / 'big.parquet'}: 3000000 rows, more than 1000000 (split the "
        "export, or raise source.max_rows)"], err
    with open(tmp_path / "one-line.csv", "wb") as f:
        for _ in range(50):
            f.write(b"9," * 500_000)
    rc, err, rss2 = _import_rss("--map", str(mp), "--scans", str(tmp_path / "one-line.csv"),
                                "--out", str(tmp_path / "b.mcap"))
    assert rc == 2 and err.strip().splitlines() == [
        f"softsensor: {tmp_path / 'one-line.csv'}: line 1 is longer than 65536 bytes (not a "
        "historian export, or the wrong delimiter?)"], err
    # no more memory than looking at the shipped 720-row export: the interpreter and its
    # libraries (240 to 480 MB here, with the load), none for the refused data
    rc, err, base = _import_rss("--map", str(mp), "--scans", str(REPLAY / "historian-example.csv"),
                                "--preview", "1")
    assert rc == 0, err
    assert max(rss, rss2) < base + 100, (rss, rss2, base)
    assert not (tmp_path / "a.mcap").exists() and not (tmp_path / "b.mcap").exists()
