"""Fixtures of the diagnosis tests: one clean 14 h virtual-plant day of the reference plant that
the tests of the windows, the problem, the residual statistics, the extensions, the verdict
and the report's numbers all read (simulated once per worker: the tests copy what they
change)."""

from __future__ import annotations

import pytest

from softsensor.plant.simulator import simulate_day


@pytest.fixture(scope="session")
def day(config):
    return simulate_day(config, 14.0, seed=5)
