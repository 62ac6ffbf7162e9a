"""The plant's own inferential sensor inside the virtual sensor
(``softsensor/estimation/lab_regression.py``): the regression of the lab on the scanned
signals, its fit, its PARAMS.toml table and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.errors import ConfigError
from softsensor.estimation.lab_regression import (
    REGRESSION_SIGNALS,
    LabRegression,
    fit_lab_regression,
    regression_of,
)
from softsensor.plantconfig import load_plant_config, with_table

CFG = load_plant_config()


def synthetic_history(seed: int = 0, days: int = 3, per_day: int = 12):
    rng = np.random.default_rng(seed)
    beta = rng.normal(size=len(REGRESSION_SIGNALS)) * 0.01
    out = []
    for _ in range(days):
        X = 300.0 + rng.normal(size=(per_day, len(REGRESSION_SIGNALS))) * 5.0
        y = 0.1 + (X - 300.0) @ beta / 5.0 + rng.normal(size=per_day) * 0.001
        out.append((X, y))
    return out, beta


def test_the_regression_fit_recovers_a_linear_lab_and_round_trips_through_params():
    hist, beta = synthetic_history()
    reg = fit_lab_regression(hist)
    X = 300.0 + np.eye(len(REGRESSION_SIGNALS)) * 5.0
    slope = (reg.predict(X) - reg.predict(np.full((1, len(REGRESSION_SIGNALS)), 300.0)))
    assert np.allclose(slope, beta, atol=0.002)
    # the bias-updated regression misses the next lab by about sqrt(2) x the lab noise
    assert 0.0005 < reg.step_sd < 0.005 and reg.hold_sd > reg.step_sd
    cfg = with_table(CFG, "regression", reg.to_table())
    back = regression_of(cfg)
    assert isinstance(back, LabRegression)
    assert np.array_equal(back.predict(X), reg.predict(X))
    means = dict(zip(REGRESSION_SIGNALS, X[0], strict=True))
    assert back.at_means(means) == pytest.approx(float(reg.predict(X[:1])[0]))


@pytest.mark.parametrize("key, bad, words", [
    ("coef", [1.0], "regression].coef must be"),
    ("signals", ["T_air_in", "speed"], "regression].signals must list"),
    ("step_sd", -1.0, "regression].step_sd must be"),
])
def test_a_bad_regression_table_is_refused_naming_the_key(key, bad, words):
    table = fit_lab_regression(synthetic_history()[0]).to_table()
    cfg = with_table(CFG, "regression", {**table, key: bad})
    with pytest.raises(ConfigError, match=words.replace("[", r"\[").replace("]", r"\]")):
        regression_of(cfg)


def test_too_short_a_history_for_the_regression_says_so():
    hist, _ = synthetic_history(days=1, per_day=5)
    with pytest.raises(ConfigError, match="needs at least 12 lab results"):
        fit_lab_regression(hist)
