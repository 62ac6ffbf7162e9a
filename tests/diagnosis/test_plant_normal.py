"""The plant's own normal verdicts (issue 48 item 1): probabilities judged against what the
plant's healthy history days showed, a stated base rate, and "too little history".

The numbers here are properties of the rule, not of a plant: a history day with an event in
it does not move the null (median and MAD), a day at the history's median carries no
evidence, no cause is given more than the cap without enough history. The end-to-end checks
on a plant the diagnosis was not tuned on (plant seed 8203 of the independent virtual plant,
``tests/support/plant_normal_fixture.py``) read the normal learned from its history, kept in
``tests/fixtures/plant_normal`` (the slow test learns it afresh and asserts the same).
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import plant_normal_fixture as fx
import pytest

from softsensor.diagnosis.diagnose_day import diagnose
from softsensor.diagnosis.plant_normal import (
    MIN_SD,
    HistoryDay,
    PlantNormal,
    history_check,
    normal_path,
    read_plant_normal,
)
from softsensor.diagnosis.posterior import capped, normal_probabilities
from softsensor.diagnosis.settings import DiagnosisSettings
from softsensor.plant.independent import simulate_independent_day
from softsensor.plantconfig import load_parameters, load_plant_config
from softsensor.presentation.verdicts import diagnosis_verdict

CAUSES = ("sensor_bias", "lab_delay", "fouling_drift", "unexplained")


def _normal(values: dict[str, list[float]], errors=None) -> PlantNormal:
    n = len(next(iter(values.values())))
    days = tuple(HistoryDay(f"d{i}", 12.0, {c: v[i] for c, v in values.items()}, "none",
                            errors[i] if errors else {}) for i in range(n))
    return PlantNormal(days, "x", "test")


def test_a_history_day_with_an_event_does_not_move_the_null():
    quiet = [-12.0, -11.0, -13.0, -12.5, -11.5, -12.0]
    a = _normal({"sensor_bias": quiet + [-12.2]})
    b = _normal({"sensor_bias": quiet + [180.0]})  # a day of the history with an offset
    assert a.spread("sensor_bias")[0] == pytest.approx(b.spread("sensor_bias")[0], abs=0.3)
    assert b.spread("sensor_bias")[1] < 2.0
    # so a real offset later still counts
    assert b.log_bayes_bound("sensor_bias", 100.0) > 50.0


def test_the_bound_is_sellke_bayarri_berger_and_never_above_the_models_own():
    # a plant whose healthy days reach 10 nats of lab-delay evidence
    nm = _normal({"lab_delay": [10.0, 12.7, 7.3, 11.349, 8.651, 10.0, 10.2]})
    m, s = nm.spread("lab_delay")
    assert (m, s) == pytest.approx((10.0, 1.4826 * 1.349))
    assert _normal({"lab_delay": [1.0, 1.1, 0.9]}).spread("lab_delay")[1] == MIN_SD
    # at the median, and anywhere with a tail probability above 1/e, no evidence
    assert nm.log_bayes_bound("lab_delay", m) == 0.0
    # three spreads out: 1 / (-e p ln p) = 41
    assert math.exp(nm.log_bayes_bound("lab_delay", m + 3 * s)) == pytest.approx(41, rel=0.05)
    # never more than the model's own evidence, and a cause the day cannot show stays out
    assert nm.log_bayes_bound("lab_delay", 2.5) <= 0.0
    # far out the model's evidence binds, less what a typical healthy day reaches
    assert nm.log_bayes_bound("lab_delay", 60.0) == pytest.approx(50.0)
    assert nm.log_bayes_bound("lab_delay", -math.inf) == -math.inf
    assert nm.log_bayes_bound("input_lag", 5.0) is None


def _ev(e: dict[str, float]) -> list[tuple[str, str | None, float, str]]:
    return [("none", None, 0.0, "baseline")] + [(c, None, x, "extension") for c, x in e.items()]


def test_a_day_like_the_healthy_history_is_none_at_about_the_base_rate():
    hist = {c: list(np.linspace(-3.0, 6.0, 8)) for c in CAUSES}
    nm = _normal(hist)
    # every candidate as far as the history's healthiest-looking day went: still none
    p = normal_probabilities(_ev({c: 6.0 for c in CAUSES}), nm, 0.9)
    assert p[0] > 0.85
    # a cause far beyond anything healthy is named, by the model's evidence
    p = normal_probabilities(_ev({**{c: 0.0 for c in CAUSES}, "sensor_bias": 60.0}), nm, 0.9)
    assert p[1] > 0.99
    # the base rate is the prior: a lower one makes the same evidence more probable
    q = normal_probabilities(_ev({**{c: 0.0 for c in CAUSES}, "lab_delay": 20.0}), nm, 0.9)
    r = normal_probabilities(_ev({**{c: 0.0 for c in CAUSES}, "lab_delay": 20.0}), nm, 0.5)
    assert r[2] > q[2]


def test_without_enough_history_no_cause_is_above_the_cap():
    p = capped(np.array([0.01, 0.917, 0.05, 0.023]), 0, 0.5)
    assert p.sum() == pytest.approx(1.0)
    assert p[1] == pytest.approx(0.5) and p[1:].max() <= 0.5 + 1e-12
    assert np.argmax(p) == 1  # the evidence still leans the same way
    p = capped(np.array([0.02, 0.49, 0.49]), 0, 0.3)
    assert p[1:].max() <= 0.3 + 1e-12 and p[0] > 0.3


def test_history_check_judges_a_day_against_the_spread_of_the_history_days():
    errs = [{"sensor": {"T_dryer_out": x, "T_cyclone_out": x, "moisture_out": 0.004}}
            for x in (0.20, 0.22, 0.21, 0.19, 0.30)]
    nm = _normal({"none_seen": [0.0] * 5}, errs)
    ok = history_check(nm, "sensor", {"T_dryer_out": 0.29, "T_cyclone_out": 0.2,
                                      "moisture_out": 0.004})
    assert {c["verdict"] for c in ok.values()} == {"within"}
    bad = history_check(nm, "sensor", {"T_dryer_out": 0.9, "T_cyclone_out": 0.2,
                                       "moisture_out": 0.004})
    assert bad["T_dryer_out"]["verdict"] == "beyond"
    assert history_check(None, "sensor", {"T_dryer_out": 0.2})["T_dryer_out"]["verdict"] \
        == "unknown"


def test_a_normal_learned_for_other_parameters_is_not_used(tmp_path):
    params = tmp_path / "p.toml"
    params.write_text("[parameters]\n")
    nm = PlantNormal((), "not the digest", "test")
    nm.write(params)
    assert normal_path(params).name == "p.plant-normal.json"
    normal, why = read_plant_normal(params)
    assert normal is None and "other parameters" in why


# ---------------------------------------------------------------- on a plant not tuned on
@pytest.fixture(scope="module")
def fixture_plant(tmp_path_factory):
    """The kept plant-normal fixture (module docstring), copied so that its digests match."""
    out = tmp_path_factory.mktemp("plant_normal")
    for f in fx.FIXTURES.iterdir():
        shutil.copy(f, out / f.name)
    cfg = load_plant_config()
    return cfg, {n: out / f"params_{k}.toml" for n, k in
                 (("full", len(fx.HISTORY_SEEDS)), ("short", fx.SHORT))}


def _judged(cfg, params: Path, day):
    normal, why = read_plant_normal(params)
    assert normal is not None, why
    return diagnose(load_parameters(params, cfg), day, normal=normal).to_json()


#: Healthy held-out days of the fixture plant (none of them in its history).
HEALTHY_SEED = 301


def test_a_healthy_held_out_day_is_none_against_the_plants_normal(fixture_plant):
    cfg, params = fixture_plant
    day = simulate_independent_day(cfg, fx.HOURS, HEALTHY_SEED, plant_seed=fx.PLANT)
    doc = _judged(cfg, params["full"], day)
    p = {c["cause"]: c["probability"] for c in doc["probabilities"]}
    assert doc["cause"] == "none", doc["probabilities"][:3]
    assert p["none"] > 0.8, doc["probabilities"][:3]
    assert doc["plant_normal"]["enough"] is True
    assert doc["plant_normal"]["history_days"] == len(fx.HISTORY_SEEDS)


def test_three_days_of_history_name_no_instrument_at_0_9(fixture_plant):
    cfg, params = fixture_plant
    day = simulate_independent_day(cfg, fx.HOURS, HEALTHY_SEED, plant_seed=fx.PLANT)
    doc = _judged(cfg, params["short"], day)
    assert doc["plant_normal"]["enough"] is False
    cap = DiagnosisSettings().cap_without_history
    assert all(c["probability"] <= cap + 1e-6 for c in doc["probabilities"]
               if c["cause"] != "none"), doc["probabilities"][:3]
    verdict = diagnosis_verdict(doc)
    assert verdict.startswith("Too little history to know this plant's normal (3 history "
                              "day(s) judged, 7 needed"), verdict
    assert doc["cause"] == "none" or "leans" in verdict


def test_an_offset_day_is_still_named_against_the_plants_normal(fixture_plant):
    cfg, params = fixture_plant
    day = simulate_independent_day(cfg, fx.HOURS, HEALTHY_SEED, "sensor_bias", 3.0,
                                   plant_seed=fx.PLANT)
    doc = _judged(cfg, params["full"], day)
    assert doc["cause"] == "sensor_bias", doc["probabilities"][:3]
    assert doc["channel"] == day.effect["channel"]
    assert doc["probabilities"][0]["probability"] > 0.9


@pytest.mark.slow
def test_the_kept_fixture_is_what_learning_the_normal_gives(tmp_path):
    """Learn the fixture plant's normal afresh (minutes) and require what the default suite
    asserts on the kept copy: the healthy held-out day is ``none``."""
    paths = fx.build(tmp_path)
    cfg = load_plant_config()
    day = simulate_independent_day(cfg, fx.HOURS, HEALTHY_SEED, plant_seed=fx.PLANT)
    doc = _judged(cfg, paths["full"], day)
    assert doc["cause"] == "none" and doc["probabilities"][0]["probability"] > 0.8
