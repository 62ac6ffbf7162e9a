"""Shared test helpers."""

import numpy as np
import pytest


@pytest.fixture
def scalar_and_array():
    """Check that ``fn`` takes a scalar and an array alike (pvlib's habit for physics
    functions): an array of three gives three values, each equal to the scalar call."""

    def check(fn, x):
        x = np.asarray(x, float)
        arr = fn(x)
        assert np.shape(arr) == x.shape
        for i, v in enumerate(x):
            s = fn(float(v))
            assert np.ndim(s) == 0
            assert s == pytest.approx(arr[i], rel=1e-14)

    return check


@pytest.fixture(scope="session")
def config():
    """The built-in reference plant ``dryer1``."""
    from softsensor.plantconfig import load_plant_config

    return load_plant_config()


@pytest.fixture(scope="session")
def cfg(config):
    """The reference plant under the short name the model, plant, diagnosis and design tests
    give it."""
    return config


@pytest.fixture(scope="session")
def model(config):
    """The model of the reference plant (files that need another grid define their own)."""
    from softsensor.model import DryerModel

    return DryerModel(config)
