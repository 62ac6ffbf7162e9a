"""Shared test helpers."""

import logging

import numpy as np
import pytest


@pytest.fixture(autouse=True)
def _root_logging_restored():
    """Undo what a test's in-process ``softsensor run`` did to the root logger's handlers
    (:func:`softsensor.service.logs.configure_logging` sets their formatter and adds its
    library-line filter): pytest's log-capturing handlers live for the whole session, so a
    filter left on them would throttle the next tests' captured lines."""
    root = logging.getLogger()
    before = {h: (h.formatter, list(h.filters)) for h in root.handlers}
    level = root.level
    yield
    for handler in list(root.handlers):
        if handler in before:
            handler.setFormatter(before[handler][0])
            handler.filters[:] = before[handler][1]
        elif type(handler) is logging.StreamHandler:  # one the test's run added
            root.removeHandler(handler)
    root.setLevel(level)


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


@pytest.fixture(scope="session")
def clean_14h_day(config):
    """A clean 14 h virtual-plant day of the reference plant (seed 5): the diagnosis tests'
    day (``tests/diagnosis/conftest.py``), simulated once per worker; the tests copy what they
    change."""
    from softsensor.plant.simulator import simulate_day

    return simulate_day(config, 14.0, seed=5)


@pytest.fixture(scope="session")
def offset_diagnosis(config, clean_14h_day):
    """The diagnosis of that day with a +3 K offset on the dryer outlet thermometer, two
    extensions tried (a sensor offset, a lab time shift): the report's numbers
    (``tests/diagnosis/test_diagnose_day.py``) and the report page's evidence table
    (``tests/presentation/test_diagnosis_report.py``) read the same one."""
    from softsensor.diagnosis.diagnose_day import diagnose
    from softsensor.diagnosis.extensions import LabTimeShift, SensorOffset
    from softsensor.plant.simulator import SimulatedDay

    day = clean_14h_day
    scans = day.scans.copy()
    scans["T_dryer_out"] += 3.0
    return diagnose(config, SimulatedDay(scans, day.labs, day.truth),
                    extensions=(SensorOffset(), LabTimeShift()))
