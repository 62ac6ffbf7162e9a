"""The import's operating envelope and unit hints (``softsensor/ingest/envelope.py``), through
``softsensor import`` and its preview (issue 30, item 3): a flow in t/h declared kg/h lies
inside the physical range but outside what the estimator accepts, and is refused naming the
unit; a LIMS column that says wet basis in % while the map says dry kg/kg is named."""

from __future__ import annotations

import re

from historian_files import kg_per_h_map
from paths import REPLAY

from softsensor.plantconfig import default_config_path


def test_a_flow_in_t_per_h_declared_kg_per_h_is_refused_naming_the_unit(tmp_path, capsys):
    """0.006 kg/s lies inside the import's physical range of m_fiber but far below what the
    estimator accepts: the import refuses it in one line naming the signal, the unit declared
    and the likely right one (it wrote the day, exit 0, and replay then blamed
    solver.scan_period); the preview names it too, and the config's [plausibility] table is
    the envelope held against."""
    from softsensor.cli import main

    hmap = kg_per_h_map(tmp_path)
    scans = str(REPLAY / "historian-example.csv")
    out = tmp_path / "day.mcap"
    assert main(["import", "--map", str(hmap), "--scans", scans, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert re.search(r"WI-4713\.PV \(signals\.m_fiber\) read as 'kg/h': 719 of 719 values "
                     r"outside the operating envelope 2\.\.10 kg/s .* in 't/h' they fall inside "
                     r"\(median 5\.86\d kg/s\): set signals\.m_fiber\.unit = 't/h'", err), err
    assert not out.exists()
    assert main(["import", "--map", str(hmap), "--scans", scans, "--preview", "2"]) == 0
    shown = capsys.readouterr().out
    row = next(line for line in shown.splitlines() if line.startswith("m_fiber"))
    assert re.search(r"-0\.5\.\.20\s+2\.\.10\s+100%", row), row
    assert "SUSPECT unit, the import refuses it:" in shown and "'t/h'" in shown
    # a plant that really runs there says so in its config, and the import takes it
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_path().read_text()
                   + "\n[plausibility.m_fiber]\nlow = 0.001\nhigh = 10.0\n")
    assert main(["import", "--map", str(hmap), "--scans", scans, "--out", str(out),
                 "--config", str(cfg)]) == 0
    assert out.exists()


def test_the_lab_preview_shows_values_as_read_and_converted_and_a_suspect_header(tmp_path,
                                                                                 capsys):
    """A LIMS column headed "Moisture %wb" holding fractions, declared kg/kg on a dry basis
    (it imported 11 % low without a word): the preview shows each result as read and as
    converted and names the basis to set; the import warns."""
    from softsensor.cli import main

    lab = ('[lab]\nsample_time_column = "Sample Time"\navailable_column = "Result Time"\n'
           'moisture_column = "Moisture %wb"\nsample_id_column = "Sample ID"\n'
           'unit = "kg/kg"\nbasis = "dry"\ndayfirst = true\n')
    hmap = kg_per_h_map(tmp_path, lab).read_text().replace(
        '[signals.m_fiber]\ncolumn = "WI-4713.PV"\nunit = "kg/h"',
        '[signals.m_fiber]\ncolumn = "WI-4713.PV"\nunit = "t/h"')
    (tmp_path / "map.toml").write_text(hmap)
    lims = tmp_path / "lims.csv"
    lims.write_text("Sample ID,Sample Time,Result Time,Moisture %wb\n"
                    "S1,05/01/2026 01:31:15,05/01/2026 02:00:49,0.0996\n"
                    "S2,05/01/2026 05:20:42,05/01/2026 06:39:17,0.1044\n")
    args = ["import", "--map", str(tmp_path / "map.toml"), "--scans",
            str(REPLAY / "historian-example.csv"), "--lab", str(lims)]
    assert main([*args, "--preview", "2"]) == 0
    shown = capsys.readouterr().out
    assert re.search(r"S1\s+2026-01-05T01:31:15\+01:00\s+0\.0996\s+0\.0996\s+9\.06", shown), shown
    assert ("SUSPECT lab unit: the lab column 'Moisture %wb' says wet basis but lab.basis is "
            "\"dry\" (set lab.basis = \"wet\")") in shown
    assert "says % but lab.unit is 'kg/kg' and its values look like fractions" in shown
    assert main([*args, "--out", str(tmp_path / "day.mcap")]) == 0
    err = capsys.readouterr().err
    assert "warning: " in err and "set lab.basis = \"wet\"" in err
