"""Reading an export's cells (``softsensor/ingest/cells.py``): a Spanish or German spreadsheet
export (';' between fields, ',' as the decimal mark) is refused naming the delimiter and the
decimal to set, and imports once they are set (issue 30, item 8)."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
from paths import REPLAY

from softsensor.recording.mcap_day import read_day


def _european(tmp_path: Path) -> Path:
    """The shipped example written as a Spanish Excel saves it: ';' between fields, ','
    as the decimal mark."""
    out = tmp_path / "export-es.csv"
    lines = []
    for line in (REPLAY / "historian-example.csv").read_text().splitlines():
        cells = [re.sub(r"^(-?\d+)\.(\d+)$", r"\1,\2", c) for c in line.split(",")]
        lines.append(";".join(cells))
    out.write_text("\n".join(lines) + "\n")
    return out


def test_a_semicolon_export_with_decimal_commas_names_delimiter_and_decimal(tmp_path, capsys):
    from softsensor.cli import main

    export = _european(tmp_path)
    text = (REPLAY / "historian-map.toml").read_text()
    cases = [(text, r"the header is one column holding ';': set source\.delimiter = ';', "
                    r"and source\.decimal = ','"),
             (text.replace("[source]\n", "[source]\ndelimiter = \";\"\n"),
              r"row 1: TI-4711\.PV value '209,85' is written with a decimal comma: set "
              r"source\.decimal = ','")]
    for map_text, pattern in cases:
        (tmp_path / "map.toml").write_text(map_text)
        assert main(["import", "--map", str(tmp_path / "map.toml"), "--scans", str(export),
                     "--preview"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and re.search(pattern, err), err
        assert "bad_values" not in err and "skip_rows" not in err, err
    (tmp_path / "map.toml").write_text(
        text.replace("[source]\n", "[source]\ndelimiter = \";\"\ndecimal = \",\"\n"))
    assert main(["import", "--map", str(tmp_path / "map.toml"), "--scans", str(export),
                 "--out", str(tmp_path / "day.mcap")]) == 0
    # every value as the original, '.'-decimal export gives it: a parse that dropped the
    # fractions, or read '209,85' as 20985, would differ
    (tmp_path / "plain.toml").write_text(text)
    assert main(["import", "--map", str(tmp_path / "plain.toml"), "--scans",
                 str(REPLAY / "historian-example.csv"), "--out",
                 str(tmp_path / "plain.mcap")]) == 0
    got, want = (read_day(tmp_path / name).scans for name in ("day.mcap", "plain.mcap"))
    pd.testing.assert_frame_equal(got, want)
