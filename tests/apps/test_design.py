"""``softsensor design`` (``softsensor/apps/design.py``): the model in the plant's loop tracking a
set-point step, the files the verb writes in plant units beside SI, and bad limits refused in
one line with exit 2 (issue 15)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softsensor.apps.design import ModelLoop
from softsensor.calibration.experiment_design import DesignLimits, schedule_from_levels
from softsensor.cli import main


def test_model_loop_tracks_a_set_point_step(cfg):
    loop = ModelLoop(cfg, cfg.nominal_inputs(), 348.0)
    lim = DesignLimits(T_sp_band=(347.0, 349.0), m_air_band=(81.0, 83.0), hours=1.0,
                       move_minutes=30.0)
    s = schedule_from_levels(np.array([[0.0, 1.0], [0.0, 0.0]]), lim, 348.0, 82.0, loop.dt)
    p = loop.run(s, cfg.parameter_vector())
    assert p.Y[-1, 0] == pytest.approx(349.0, abs=0.1)
    assert p.U[-1, 0] > p.U[0, 0] + 1.0  # more hot gas for a hotter outlet


def test_verb_writes_its_files(tmp_path, capsys):
    out = tmp_path / "d"
    rc = main(["design", "--out", str(out), "--hours", "1.5", "--budget", "2", "--random", "1",
               "--lab-minutes", "20", "--T-sp-band", "73.85", "76.35", "--quiet"])
    assert rc == 0
    for name in ("schedule.csv", "schedule.json", "prediction.csv", "design.png",
                 "design.svg", "design.json"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0
    rows = json.loads((out / "schedule.json").read_text())["schedule"]
    assert len(rows) == 91 and all(347 <= r["T_sp_K"] <= 349.5 + 1e-9 for r in rows)
    # the operator's units beside SI (issue 30: design spoke K and kg/s only)
    assert all(r["T_sp_degC"] == pytest.approx(r["T_sp_K"] - 273.15, abs=0.01)
               and r["m_air_t_h"] == pytest.approx(3.6 * r["m_air_kg_s"], abs=0.01)
               for r in rows)
    assert capsys.readouterr().err.count("\n") == 1  # --quiet: the last line only
    doc = json.loads((out / "design.json").read_text())
    assert "logdet_ratio_weighted_fim" in doc["gain"]
    header = (out / "schedule.csv").read_text().splitlines()[0]
    assert header == "time_s,time_utc,T_sp_K,m_air_kg_s,T_sp_degC,m_air_t_h"


@pytest.mark.parametrize("extra, words", [
    (["--T-sp-band", "77", "73"], "--T-sp-band must be LOW < HIGH [°C], got 77 73"),
    (["--T-sp-band", "77", "79"], "the operating point's 74.85 °C lies outside its band"),
    (["--m-air-band", "300", "310"], "--m-air-band 300 310 [t/h]: the operating point's 295.2 "
                                     "t/h lies outside"),
    (["--max-moisture-excursion", "-1"], "moisture excursion"),
    (["--T-sp-rate", "0"], "T_sp rate"),
])
def test_verb_bad_limits_one_line_exit_2(tmp_path, capsys, extra, words):
    rc = main(["design", "--out", str(tmp_path / "x"), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and words in err
    assert not (tmp_path / "x").exists()
