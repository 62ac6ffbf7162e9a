"""Calibration from the plant's history (``softsensor/calibration/history_calibration.py``): the
regression peer fitted on the history's days."""

from __future__ import annotations

import numpy as np

from softsensor.estimation.lab_regression import REGRESSION_SIGNALS


def test_calibrate_fits_the_regression_on_the_signals_every_day_scanned(capsys):
    from types import SimpleNamespace

    import pandas as pd

    from softsensor.calibration.history_calibration import history_regression

    rng = np.random.default_rng(5)
    t = (np.arange(1, 8641) * 10 + 1_767_571_200) * 10**9  # 24 h of 10 s scans
    days = []
    for _ in range(2):
        scans = pd.DataFrame({s: 300 + rng.normal(size=len(t)) for s in REGRESSION_SIGNALS},
                             index=t)
        scans["flap_cmd"] = np.nan  # not read on this plant
        sample = t[::720][1:] - 5 * 10**9  # one every 2 h
        mean = scans["T_air_in"].rolling(60).mean().reindex(sample, method="ffill")
        value = 0.1 + 0.01 * (mean - 300)
        days.append(SimpleNamespace(scans=scans, labs=pd.DataFrame(
            {"sample_time_ns": sample, "moisture_out": value.to_numpy()})))
    reg, why = history_regression(days)
    assert why is None
    assert "flap_cmd" not in reg.signals and len(reg.signals) == len(REGRESSION_SIGNALS) - 1
    assert reg.n_labs == 22
    assert np.all(np.isfinite(reg.coef)) and reg.step_sd > 0
    short = SimpleNamespace(scans=days[0].scans, labs=days[0].labs.iloc[:9])
    reg, why = history_regression([short])
    assert reg is None  # 9 results for 11 coefficients
    assert why == ("the regression peer needs at least 11 lab results with every signal "
                   "scanned, the history holds 9")
