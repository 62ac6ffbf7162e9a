"""One display setting in every human output (issue 24, item 3): the validation page said
"1.42 % points (dry basis)" where the terminal said "1.13 % points (wet basis)" for the same
run with a wet-basis config, and its tables were in K and kg/kg under a verdict in °C and %.
Here ``softsensor validate --report`` runs on the shipped plant export and the page's verdict,
its tables and the terminal line must say the same numbers in the same units."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from paths import REPLAY

from softsensor.calibration.params_file import params_document, write_params
from softsensor.cli import main as cli_main
from softsensor.plantconfig import default_config_path, load_plant_config


@pytest.fixture(scope="module")
def day(tmp_path_factory) -> tuple[Path, Path, Path]:
    d = tmp_path_factory.mktemp("units")
    out = d / "day.mcap"
    assert cli_main(["import", "--map", str(REPLAY / "historian-map.toml"), "--scans",
                     str(REPLAY / "historian-example.csv"), "--lab",
                     str(REPLAY / "lims-example.csv"), "--out", str(out)]) == 0
    config = d / "plant.toml"
    config.write_text(default_config_path().read_text()
                      + '\n[display]\ntime_zone = "Europe/Madrid"\nmoisture_basis = "wet"\n')
    cfg = load_plant_config(config)
    params = write_params(d / "params.toml", params_document(
        cfg, {n: s.value for n, s in cfg.parameters.items()}, {"cost": 0.05}))
    return out, config, params


def test_the_validation_page_and_the_terminal_say_the_same_in_the_display_units(day, tmp_path,
                                                                                capsys):
    out, config, params = day
    capsys.readouterr()
    rc = cli_main(["validate", str(out), "--params", str(params), "--config", str(config),
                   "--report", str(tmp_path / "report")])
    err = capsys.readouterr().err
    assert rc == 0, err
    line = err.strip().splitlines()[-1]
    terminal = re.search(r"outlet moisture ([\d.]+) % points \((\w+) basis\)", line)
    assert terminal and terminal.group(2) == "wet", line
    page = (tmp_path / "report" / "index.html").read_text()
    verdict = re.search(r'<p class="verdict">(.*?)</p>', page, re.S).group(1)
    shown = re.search(r"outlet moisture ([\d.]+) % points \((\w+) basis\)", verdict)
    assert shown and shown.groups() == terminal.groups(), (verdict, line)
    for name in ("dryer outlet", "cyclone outlet"):
        a = re.search(rf"{name} ([\d.]+) °C", line).group(1)
        assert f"{name} {a} °C" in verdict, (verdict, line)
    # the tables under it: °C and % points on the wet basis, not K and kg/kg
    rows = re.findall(r"<tr>\s*<td>(T_dryer_out|moisture_out)</td>\s*<td>([^<]*)</td>", page)
    assert ("T_dryer_out", "°C") in rows and ("moisture_out", "% points (wet basis)") in rows
    assert not re.search(r"<td>(K|kg/kg)</td>", page)
