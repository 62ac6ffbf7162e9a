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


def _result(new_mo: float, old_mo: float):
    from types import SimpleNamespace

    def ev(mo):
        return SimpleNamespace(fit=SimpleNamespace(rmse={"moisture_out": mo}))

    return SimpleNamespace(validation=ev(new_mo), current_validation=ev(old_mo),
                           theta=np.ones(7), discrepancy=None)


def test_a_fit_whose_held_out_labs_are_worse_needs_the_sensors_own_lab_score(monkeypatch):
    """Issue 47: accepted on the weighted cost while the held-out labs got worse, a
    calibration is deployed only when the estimator's lab score on the latest days says it
    is better (by more than its standard error, failing no more results)."""
    import softsensor.calibration.history_calibration as hc
    from softsensor.calibration.sensor_score import SensorScore

    assert hc.labs_worse(_result(0.012, 0.010)) and not hc.labs_worse(_result(0.010, 0.012))
    per = {}

    def score(diff):
        def fake(config, days):
            side = "calibrated" if config == "calibrated" else "current"
            base = np.linspace(2.0, 3.0, 40)
            logs = base + (diff if side == "calibrated" else 0.0) + np.sin(np.arange(40)) * 0.1
            per[side] = {f"0:{i}": float(v) for i, v in enumerate(logs)}
            return SensorScore(float(np.mean(logs)), 0.01, 40, per[side])
        return fake

    monkeypatch.setattr(hc, "learned_error", lambda model, days, th, result: ([1.0], th))
    monkeypatch.setattr(hc, "deployable",
                        lambda cfg, th, me, disc: "calibrated" if th[0] == 1.0 else "current")
    monkeypatch.setattr(hc, "latest_days", lambda days: days)
    monkeypatch.setattr(hc, "deployed_discrepancy", lambda result, kept: None)
    learned = {}
    for diff, want in ((0.5, True), (0.0, False), (-0.5, False)):
        monkeypatch.setattr(hc, "sensor_score", score(diff))
        better, why = hc.sensor_accepts([], None, None, _result(0.012, 0.010),
                                        np.zeros(7), learned)
        assert better is want, why
        assert learned["baseline"][1][0] == (1.0 if want else 0.0)
