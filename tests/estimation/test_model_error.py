"""The model's error learned from history: PARAMS.toml's ``[model_error]`` (its table, its
evaluation) and the statistics that learn it (:mod:`softsensor.calibration.model_error_fit`)
on residuals whose truth is known."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from softsensor.calibration.model_error_fit import _channel, _Rows
from softsensor.calibration.params_file import params_document, write_params
from softsensor.errors import ConfigError
from softsensor.estimation.model_error import (
    CHANNELS,
    FEATURES,
    ChannelError,
    ModelError,
    model_error_from_table,
    model_error_of,
)
from softsensor.plantconfig import load_parameters, load_plant_config

CFG = load_plant_config()
F = len(FEATURES)


def _error(seed: int = 0) -> ModelError:
    rng = np.random.default_rng(seed)

    def channel(scale: float) -> ChannelError:
        A = rng.normal(size=(F, F)) * 0.1 * scale
        return ChannelError(coef=tuple(rng.normal(size=F) * scale),
                            coef_cov=tuple((A @ A.T).ravel()), intercept=0.3 * scale,
                            day_sd=0.5 * scale, walk=0.1 * scale, noise=0.2 * scale,
                            rmse_without=0.8 * scale, rmse_held_out=0.4 * scale, samples=900)

    return ModelError(features=FEATURES, mean=tuple(rng.uniform(1, 500, F)),
                      scale=tuple(rng.uniform(0.1, 5, F)), T_dryer_out=channel(1.0),
                      T_cyclone_out=channel(1.0), moisture_out=channel(0.01), days=7,
                      hours=336.0, moisture_in=1.02, moisture_in_day_sd=0.01)


def test_table_round_trips_through_params_toml(tmp_path):
    me = _error()
    path = write_params(tmp_path / "p.toml", params_document(
        CFG, dict(zip(("mult_D",), (1.0,), strict=True)) | {
            n: CFG.parameters[n].value for n in CFG.parameters}, {}, model_error=me.to_table()))
    cfg = load_parameters(path, CFG)
    assert model_error_of(cfg) == me
    assert model_error_of(CFG) is None


@pytest.mark.parametrize(("edit", "words"), [
    (lambda t: t["T_dryer_out"].update(coef_cvo=[1.0]), "model_error.T_dryer_out.coef_cvo "
                                                         "is not a known key"),
    (lambda t: t["moisture_out"].update(coef=[0.0] * (F - 1)),
     r"model_error.moisture_out.coef_cov must hold 49 numbers \(coef has 7\)"),
    (lambda t: (t["moisture_out"].update(coef=[0.0] * (F - 1), coef_cov=[0.0] * (F - 1)**2)),
     "model_error.moisture_out.coef must hold one number per feature"),
    (lambda t: t.update(features=[*FEATURES[:-1], "T_spp"]),
     "model_error.features: 'T_spp' is not a scan signal"),
    (lambda t: t["T_cyclone_out"].update(day_sd=-1.0), "model_error.T_cyclone_out.day_sd must "
                                                       "be >= 0"),
    (lambda t: t["T_cyclone_out"].update(coef_cov=[0.0] * 3), "coef_cov must hold"),
    (lambda t: t["T_dryer_out"]["coef"].__setitem__(2, "x"),
     r"model_error.T_dryer_out.coef\[2\] must be a number"),
])
def test_a_bad_table_is_one_line_naming_the_key(edit, words):
    table = _error().to_table()
    edit(table)
    with pytest.raises(ConfigError, match=words):
        model_error_from_table(table, "p.toml")


def test_offset_is_intercept_plus_slopes_on_the_standardised_point():
    me = _error(1)
    means = {f: m + 2.0 * s for f, m, s in zip(FEATURES, me.mean, me.scale, strict=True)}
    means["m_air"] = None  # a missing feature sits at its history mean
    phi = me.phi(means)
    assert phi[FEATURES.index("m_air")] == 0.0
    assert np.all(np.delete(phi, FEATURES.index("m_air")) == pytest.approx(2.0))
    for c in CHANNELS:
        ch = me.channel(c)
        assert float(me.offset(c, phi)) == pytest.approx(ch.intercept + phi @ ch.coef)
        assert float(me.offset_var(c, phi)) == pytest.approx(phi @ ch.cov @ phi)
    # a batch of points gives the same as one at a time
    P = np.stack([phi, 0.5 * phi])
    np.testing.assert_allclose(me.offset("T_dryer_out", P),
                               [float(me.offset("T_dryer_out", p)) for p in P])


def _rows(n_days: int, per_day: int, beta: np.ndarray, day_sd: float, wander_sd: float,
          tau_h: float, noise: float, seed: int, dt_h: float = 1 / 6) -> _Rows:
    """Residuals of a known model: slopes, day offsets, a first-order wander and white
    noise."""
    rng = np.random.default_rng(seed)
    a = math.exp(-dt_h / tau_h)
    r, phi, day, t = [], [], [], []
    for i in range(n_days):
        X = rng.normal(size=(per_day, beta.size))
        level = day_sd * rng.normal()
        w = np.empty(per_day)
        w[0] = wander_sd * rng.normal()
        for k in range(1, per_day):
            w[k] = a * w[k - 1] + wander_sd * math.sqrt(1 - a * a) * rng.normal()
        r.append(X @ beta + level + w + noise * rng.normal(size=per_day))
        phi.append(X)
        day.append(np.full(per_day, i))
        t.append(dt_h * np.arange(1, per_day + 1))
    return _Rows(np.concatenate(r), np.vstack(phi), np.concatenate(day), np.concatenate(t))


def test_channel_fit_recovers_slopes_day_spread_wander_and_noise():
    """Seven days of 288 windows with known statistics: the slopes within four standard
    errors of the truth; the day spread, wander and noise within the sampling error of seven
    days (day spread 40 %, wander and noise 25 %, its correlation time 50 %); the level's
    walk moves it by its spread in a day."""
    beta = np.array([0.6, -0.3, 0.0, 0.1, 0.0, 0.2, -0.1, 0.4])
    ch = _channel(_rows(7, 288, beta, day_sd=0.5, wander_sd=0.25, tau_h=3.0, noise=0.2,
                        seed=4), 7)
    assert ch.learned and ch.rmse_held_out < 0.5 * ch.rmse_without
    se = np.sqrt(np.diag(ch.cov))
    assert np.all(np.abs(np.array(ch.coef) - beta) < 4 * se + 0.01)
    assert ch.day_sd == pytest.approx(0.5, rel=0.4)
    assert ch.wander_sd == pytest.approx(0.25, rel=0.25)
    assert ch.wander_tau_h == pytest.approx(3.0, rel=0.5)
    assert ch.noise == pytest.approx(0.2, rel=0.25)
    assert ch.walk == pytest.approx(ch.day_sd / math.sqrt(24.0))


def test_channel_without_a_response_learns_no_slopes():
    """Residuals that do not depend on the operating point: the held-out check keeps the
    slopes at zero (a spurious fit would only add noise to the estimator)."""
    ch = _channel(_rows(7, 20, np.zeros(F), day_sd=0.004, wander_sd=0.0, tau_h=1.0,
                        noise=0.003, seed=9), 7)
    assert not ch.learned and ch.rmse_held_out == ch.rmse_without
    assert np.all(np.asarray(ch.coef_cov) == 0.0)
    assert ch.noise == pytest.approx(0.003, rel=0.3)


def test_one_day_is_cross_validated_by_quarters():
    beta = np.zeros(F)
    beta[0] = 1.0
    ch = _channel(_rows(1, 288, beta, day_sd=0.0, wander_sd=0.0, tau_h=1.0, noise=0.1,
                        seed=2), 1)
    assert ch.learned and ch.coef[0] == pytest.approx(1.0, abs=0.05)
    assert ch.day_sd == 0.0


def test_model_error_with_zero_slopes_changes_nothing_in_the_config():
    me = dataclasses.replace(_error(), T_dryer_out=dataclasses.replace(
        _error().T_dryer_out, coef=(0.0,) * F))
    assert not me.T_dryer_out.learned and me.T_cyclone_out.learned


def test_the_estimator_starts_at_the_latest_days_inlet_level(tmp_path):
    """History gives the normal, the latest day the state (issue 28 item 3): the filter's
    inlet moisture starts at the latest history day's level, not the history's mean."""
    from softsensor.estimation.state_space import X_IN
    from softsensor.estimation.ukf import UkfEstimator

    def start(me: ModelError) -> float:
        path = write_params(tmp_path / "p.toml", params_document(
            CFG, {n: CFG.parameters[n].value for n in CFG.parameters}, {},
            model_error=me.to_table()))
        est = UkfEstimator(load_parameters(path, CFG))
        return float(est.inlet.forward(est._state.x[X_IN]))

    assert start(_error()) == pytest.approx(1.02, abs=1e-9)
    assert start(dataclasses.replace(_error(), latest_moisture_in=1.15)) == pytest.approx(
        1.15, abs=1e-9)
