"""The set-point advisor on the model itself (softsensor.advisor.advice, .search).

The plant here is the model at the reference parameters, so the advice can be checked
against the model's own steady state (an oracle through the same front door): the advised
T_air_in gives the advised T_sp as outlet temperature, and the predicted moisture there.
A coarse tube (n_d=10) keeps each advice to a fraction of a second.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from softsensor.advisor.advice import Advice, Envelope, Situation, advise
from softsensor.advisor.search import heat_duty, per_tonne
from softsensor.advisor.settings import AdvisorSettings
from softsensor.model import DryerModel
from softsensor.plantconfig import load_plant_config
from softsensor.signals import INPUT_NAMES, SCAN_SIGNALS

ENV = Envelope({"T_air_in": 420.0, "T_sp": 335.0, "m_fiber": 4.0},
               {"T_air_in": 560.0, "T_sp": 360.0, "m_fiber": 7.5})
COV = np.diag(np.full(7, 0.1**2))  # 10 % on every parameter, uncorrelated


@pytest.fixture(scope="module")
def model() -> DryerModel:
    return DryerModel(load_plant_config(), n_d=10, threads=1)


def _situation(model: DryerModel, T_air_in: float = 490.0, std: float = 0.005,
               health: str = "ok") -> Situation:
    """The model's own steady state at T_air_in, read as a settled plant whose loop holds
    T_dryer_out at T_sp."""
    u = model.nominal_inputs(T_air_in=T_air_in)
    _, y = model.steady_state(u)
    inputs = dict.fromkeys(SCAN_SIGNALS, 0.0)
    inputs.update({n: float(v) for n, v in zip(INPUT_NAMES[:-1], u[:-1], strict=True)})
    inputs.update(T_sp=float(y[0]), T_dryer_out=float(y[0]), T_cyclone_out=float(y[1]))
    return Situation(0, inputs, float(u[-1]), float(y[2]), std, health,
                     "all good" if health == "ok" else "innovations inconsistent",
                     (float(u[2]),) * 6, (float(y[0]),) * 6)


def test_advice_holds_the_target_on_the_models_own_steady_state(model):
    cfg = AdvisorSettings()
    s = _situation(model)
    a = advise(model, model.theta0, COV, s, cfg, ENV)
    assert a.advised, a.reason
    # the oracle: the model at the advised T_air_in reads the advised set point and the
    # predicted moisture (the estimate here is the model's own, so no offset)
    u = model.nominal_inputs(T_air_in=a.T_air_in_advised)
    _, y = model.steady_state(u)
    assert y[0] == pytest.approx(a.T_sp_advised, abs=0.05)
    assert y[2] == pytest.approx(a.moisture_out_advised, abs=1e-3)
    # the least heat: the target itself (within one set-point step), not drier
    assert cfg.moisture_target - 2e-3 <= a.moisture_out_advised <= cfg.moisture_target
    # less heat when the plant ran drier than the target, and the duties add up
    assert s.moisture_out < cfg.moisture_target and a.T_sp_advised < a.T_sp
    assert a.saving_kwh_per_t > 0
    assert a.saving_kwh_per_t == pytest.approx(a.duty_kwh_per_t - a.duty_advised_kwh_per_t)
    assert a.settle_s is not None and a.settle_s > 0
    assert Advice.from_body(a.to_body()) == a


def test_no_advice_while_the_health_is_not_ok(model):
    a = advise(model, model.theta0, COV, _situation(model, health="degraded"),
               AdvisorSettings(), ENV)
    assert not a.advised and a.T_sp_advised is None
    assert a.reason.startswith("health is degraded: innovations inconsistent")


def test_no_advice_when_the_band_is_wider_than_the_margin(model):
    # margin 0.01 kg/kg from target to limit; at 95 % the band half-width is 1.645 sd
    cfg = AdvisorSettings(moisture_target=0.10, moisture_max=0.11, confidence=0.95)
    narrow = advise(model, model.theta0, np.zeros((7, 7)), _situation(model, std=0.005),
                    cfg, ENV)
    assert narrow.advised, narrow.reason
    assert narrow.p_within_max >= 0.95
    wide = advise(model, model.theta0, np.zeros((7, 7)), _situation(model, std=0.0065),
                  cfg, ENV)
    assert not wide.advised
    assert "wider than the margin" in wide.reason


def test_the_parameters_covariance_widens_the_prediction(model):
    cfg = AdvisorSettings()
    s = _situation(model)
    none = advise(model, model.theta0, np.zeros((7, 7)), s, cfg, ENV)
    some = advise(model, model.theta0, COV, s, cfg, ENV)
    assert none.moisture_out_change_std == pytest.approx(0.0, abs=1e-12)
    assert none.moisture_out_advised_std == pytest.approx(s.moisture_out_std)
    # a move of the set point is uncertain through the parameters: the band grows with it
    assert some.moisture_out_change_std > 1e-4
    assert some.moisture_out_advised_std == pytest.approx(
        math.hypot(s.moisture_out_std, some.moisture_out_change_std))


def test_refusals_say_why_in_one_line(model):
    cfg = AdvisorSettings()
    s = _situation(model)
    moving = replace(s, recent_m_fiber=(5.0, 5.0, 5.5, 6.0, 6.0, 6.0))
    outside = replace(s, inputs={**s.inputs, "m_fiber": 7.8})
    nudged = replace(s, recent_T_sp=(345.0,) * 3 + (s.inputs["T_sp"],) * 3)
    blind = replace(s, moisture_out=None)
    for sit, words in ((moving, "production change"), (outside, "m_fiber 7.8 kg/s is outside"),
                       (nudged, "the set point moved"), (blind, "no estimate")):
        a = advise(model, model.theta0, COV, sit, cfg, ENV)
        assert not a.advised and a.reason.startswith(words), a.reason
        assert "\n" not in a.reason


def test_a_wet_plant_out_of_reach_is_refused_not_pushed_beyond_the_envelope(model):
    env = Envelope({**ENV.low}, {**ENV.high, "T_sp": _situation(model, 455.0).inputs["T_sp"]
                                 + 0.5})
    s = _situation(model, T_air_in=455.0)  # wet: 0.21 kg/kg, far above the target
    a = advise(model, model.theta0, COV, s, AdvisorSettings(), env)
    assert not a.advised and "beyond the envelope" in a.reason


def test_heat_duty_units():
    u = np.array([470.0, 80.0, 6.0, 370.0, 0.5, 290.0, 0.008, 1.0])
    q = heat_duty(u)
    # dry air and its vapour from 290 to 470 K: about 1.01 kJ/(kg K) and 1.9 kJ/(kg K)
    assert q == pytest.approx(80.0 * 180.0 * (1012.0 + 0.008 * 1900.0), rel=0.01)
    assert heat_duty(np.r_[290.0, u[1:]]) == pytest.approx(0.0, abs=1e-6)
    assert per_tonne(1e6, 1.0) == pytest.approx(1000.0 / 3.6)  # 1 MW at 3.6 t/h
