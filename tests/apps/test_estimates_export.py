"""``softsensor export``: the estimates of a replay as a CSV and a Parquet table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from paths import REPO

from softsensor.cli import main as cli_main
from softsensor.messages import is_number
from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_HEALTH

DEMO = REPO / "replay" / "demo-day.mcap"


@pytest.fixture(scope="module")
def estimates(tmp_path_factory) -> Path:
    """Two hours of the demo day through ``softsensor replay``."""
    out = tmp_path_factory.mktemp("export") / "est.mcap"
    assert cli_main(["replay", str(DEMO), "--end", "2026-01-05T02:00:00Z",
                     "--out", str(out)]) == 0
    return out


def test_export_has_one_row_per_estimate_with_the_same_values(estimates, tmp_path,
                                                              capsys) -> None:
    capsys.readouterr()
    rc = cli_main(["export", str(estimates), "--csv", str(tmp_path / "e.csv"),
                   "--parquet", str(tmp_path / "e.parquet"), "--all-columns"])
    out = capsys.readouterr().err
    assert rc == 0 and "13 estimates" in out, out
    rec = read_day(estimates)
    est, health = rec.topic(TOPIC_ESTIMATE), rec.topic(TOPIC_HEALTH)
    assert len(est) == 13  # 2 h of 600 s ticks and the first scan's
    for table in (pd.read_csv(tmp_path / "e.csv"), pd.read_parquet(tmp_path / "e.parquet")):
        assert len(table) == len(est)
        assert table.time_ns.tolist() == [t for t, _ in est]
        assert table.time_utc.iloc[1] == "2026-01-05T00:10:00Z"
        for key in ("moisture_out", "moisture_out_std", "moisture_in", "moisture_in_std",
                    "T_dryer_out_model", "T_cyclone_out_model", "nis"):
            want = [b[key] if is_number(b[key]) else np.nan for _, b in est]
            np.testing.assert_allclose(table[key].astype(float), want, rtol=1e-15,
                                       err_msg=key)
        assert table.lab_updated.tolist() == [int(b["lab_updated"]) for _, b in est]
        assert table.window_end_ns.tolist() == [b["window_end_ns"] for _, b in est]
        # The health in force at each tick: the last message at or before its time.
        for i, (t, _b) in enumerate(est):
            h = [b for th, b in health if th <= t][-1]
            assert table.health_status.iloc[i] == h["status"]
            assert table.health_ticks.iloc[i] == h["ticks"]
        assert "detail" not in table.columns  # text is not a number


def test_export_refuses_a_day_without_estimates_and_a_wrong_suffix(tmp_path, capsys) -> None:
    capsys.readouterr()
    assert cli_main(["export", str(DEMO), "--csv", str(tmp_path / "e.csv")]) == 2
    assert "no /softsensor/estimate messages" in capsys.readouterr().err
    assert cli_main(["export", str(DEMO), "--csv", str(tmp_path / "e.parquet")]) == 2
    assert "does not end in .csv" in capsys.readouterr().err
    assert cli_main(["export", str(DEMO)]) == 2
    assert "--csv OUT.csv and/or --parquet" in capsys.readouterr().err


def test_export_for_people_local_time_plant_units_and_no_internals(estimates, tmp_path,
                                                                  capsys) -> None:
    """Issue 24 item 3: the export was UTC, SI and dry basis only, with the estimator's
    internal columns (nis, clipped); now those are behind --all-columns and the [display]
    table of --config gives the plant's clock and % on its basis."""
    config = tmp_path / "plant.toml"
    config.write_text((DEMO.parents[1] / "config" / "dryer1.toml").read_text()
                      + '\n[display]\ntime_zone = "Europe/Madrid"\nmoisture_basis = "wet"\n')
    capsys.readouterr()
    assert cli_main(["export", str(estimates), "--csv", str(tmp_path / "si.csv")]) == 0
    si = pd.read_csv(tmp_path / "si.csv")
    assert not {"nis", "clipped", "fallback", "nis_dof"} & set(si.columns), list(si.columns)
    assert {"moisture_out", "T_dryer_out_measured", "T_dryer_out_model",
            "health_status"} <= set(si.columns)
    rc = cli_main(["export", str(estimates), "--csv", str(tmp_path / "plant.csv"), "--config",
                   str(config), "--local-time", "--plant-units"])
    err = capsys.readouterr().err
    assert rc == 0 and "2026-01-05T01:00:00+01:00 .. 2026-01-05T03:00:00+01:00" in err, err
    plant = pd.read_csv(tmp_path / "plant.csv")
    assert list(plant.columns[:3]) == ["time_utc", "time_local", "time_ns"]
    assert plant.time_local.iloc[1] == "2026-01-05T01:10:00+01:00"
    x = si.moisture_out.to_numpy()
    np.testing.assert_allclose(plant.moisture_out_wb_pct, 100 * x / (1 + x), rtol=1e-12)
    np.testing.assert_allclose(plant.T_dryer_out_model_degC, si.T_dryer_out_model - 273.15)
    std = plant.moisture_out_std_wb_pct.to_numpy()
    assert np.all((std > 0) & (std < 100 * si.moisture_out_std.to_numpy()))
    assert "moisture_out" not in plant.columns and "nis" not in plant.columns
