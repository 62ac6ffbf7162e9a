"""Events the model cannot explain, hidden in independent-plant days (issue 38, item 5).

The sensor runs as shipped (the default ``[estimator]``) with the PARAMS.toml that
``softsensor calibrate``'s code wrote from the 7 x 48 h clean history of independent plant
1697822559 (``tests/fixtures/independent_plant_params.toml``: the tuning plant of
``benchmarks/sensor_events.py``, its ``[regression]`` fitted on the same days). Each test
draws a day on that plant from a seed used nowhere in the tuning (the tuning ran the event
days of ``--seed 6262 --event-seed 777``) and hides one thing the model cannot explain:

* an unmeasured surge of the fan's flow (the recorded ``m_air`` flat, the true one
  oscillating by 4 % over 1.75 h): the temperatures move for a reason outside the model;
* a ``T_air_in`` thermometer lagging the truth by 20 min;
* production moves every 1 to 2 h, each with a set-point move.

Each asserts the estimate's swing against the truth's (the standard deviation after the daily
mean, issue 38's "within 1.5 times the truth's") and its error against holding the last lab
result, the peer every plant has (the benchmark's ``benchmarks/peers.py``, the same code).

These are the issue's targets checked on fresh days, not tests of one mechanism: they pass
with ``estimator.transient_fraction = 0`` too (RMSE 0.0084, 0.0106 and 0.0073 on the three
days, against 0.0099, 0.0111 and 0.0067 at the shipped 0.2). The widening itself is pinned by
``test_ukf.py::test_a_moving_inlet_air_temperature_widens_the_temperature_rows``.
"""

from __future__ import annotations

import math
from types import ModuleType

import pytest
from paths import FIXTURES, REPO
from script_modules import load_script

from softsensor.estimation.lab_regression import regression_of
from softsensor.plant.independent import UnmeasuredFlow, simulate_independent_day
from softsensor.plantconfig import load_parameters, load_plant_config

PARAMS = FIXTURES / "independent_plant_params.toml"
PLANT = 1697822559
HOURS = 24.0
BASE = load_plant_config()


@pytest.fixture(scope="module")
def events() -> ModuleType:
    return load_script(REPO / "benchmarks" / "sensor_events.py")


@pytest.fixture(scope="module")
def deployed():
    config = load_parameters(PARAMS, BASE)
    return config, regression_of(config)


def _score(events, deployed, day):
    config, regression = deployed
    return events.score_day(config, regression, day, BASE, PLANT)


def _check(out, swing_max: float = 1.5) -> None:
    rm, sw = out["rmse"], out["swing_ratio"]
    assert sw["softsensor"] <= swing_max, out
    assert rm["softsensor"] < rm["hold"], out
    assert math.isfinite(out["coverage95"]) and out["coverage95"] >= 0.85, out


def test_an_unmeasured_flow_surge_is_not_turned_into_moisture(events, deployed):
    day = simulate_independent_day(BASE, HOURS, 4101, plant_seed=PLANT,
                                   unmeasured_flow=UnmeasuredFlow(0.04, 6300.0, 1.0))
    _check(_score(events, deployed, day))


@pytest.mark.slow
def test_a_lagging_inlet_air_thermometer_is_not_turned_into_moisture(events, deployed):
    day = simulate_independent_day(BASE, HOURS, 4102, "input_lag", 20.0, plant_seed=PLANT)
    _check(_score(events, deployed, day))


@pytest.mark.slow
def test_production_moves_are_not_turned_into_moisture(events, deployed):
    day = simulate_independent_day(events.moves_config(BASE), HOURS, 4103, plant_seed=PLANT)
    _check(_score(events, deployed, day))
