"""Fixtures of the calibration tests: a 6 h virtual-plant day of the plant with the true
parameters (:data:`synthetic_days.TRUTH`), its 600 s segment and the paper's objective, shared by
the tests of the chunked runs, the study and the polish (simulated once per worker; no test
changes them)."""

from __future__ import annotations

import pytest
from synthetic_days import TRUTH

from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.objective import ObjectiveSpec
from softsensor.plant.simulator import simulate_day


@pytest.fixture(scope="session")
def day6(config):
    """A 6 h virtual-plant day with known (non-default) parameters."""
    return simulate_day(config.with_parameters(TRUTH), 6.0, seed=3)


@pytest.fixture(scope="session")
def segment(day6, config):
    return segment_from_day(day6, config, source="day6")


@pytest.fixture(scope="session")
def eq4(config):
    """The paper's objective: eq. 4, nominal inlet moisture, no prior."""
    return ObjectiveSpec(cost="eq4", weights=config.cost.weights())
