"""Grid convergence of the tube discretisation: n_d = 25, 50, 100 (and 200 for the rate).

Requirement (issue 2): outlet temperatures within 0.5 K and outlet moisture within 0.002 kg/kg
of each other for n_d = 25, 50, 100, at the nominal point and off-nominal points.

Finding: with plain upwind (rates at each cell's outflow state) the march was first order in
dx and n_d = 25 missed the tolerance by about 1.5x (0.7 K, 0.005 kg/kg from n_d = 100), the
error coming from the steep drying in the first metres. The tube cells now use a damped theta
scheme along x (rates at 0.4 inflow + 0.6 outflow state, see softsensor/model/kernels.py):
n_d = 25, 50 and 100 agree within 0.08 K and 0.0004 kg/kg (with the high-flux driving force
and the hold-up cyclone of 2026-11-23). From n_d = 50 on, the error against n_d = 200 halves
with each doubling; between 25 and 50 the damped scheme is not yet monotone (wet fibre at
540 K: 0.079 and 0.080 K from n_d = 400).
"""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.model import DryerModel
from softsensor.plantconfig import load_plant_config

TOL = np.array([0.5, 0.5, 0.002])  # K, K, kg/kg (T_dryer_out, T_cyclone_out, moisture_out)
#: What the model page (docs/explanation/model.md) claims for n_d = 25, 50 and 100 (measured: 0.079
#K, 0.049 K, 0.00033).
CLAIM = np.array([0.08, 0.08, 4e-4])

POINTS = {
    "nominal": {},
    "hot_low_production": {"T_air_in": 520.0, "m_fiber": 5.0},
    "cold_high_production": {"T_air_in": 460.0, "m_fiber": 7.0, "T_amb": 265.0},
    "wet_fibre": {"moisture_in": 1.3, "T_air_in": 540.0},
}


@pytest.fixture(scope="module")
def outputs():
    """Steady outputs (3,) per n_d and point, one batched steady-state call per grid."""
    res = {}
    for n_d in (25, 50, 100, 200):
        m = DryerModel(load_plant_config(), n_d=n_d)
        U = np.stack([m.nominal_inputs(**POINTS[k]) for k in sorted(POINTS)])
        _, Y = m.steady_state(U, m.theta0)
        res[n_d] = dict(zip(sorted(POINTS), Y, strict=True))
    return res


@pytest.mark.parametrize("point", sorted(POINTS))
def test_n_d_50_and_100_agree(outputs, point):
    diff = np.abs(outputs[50][point] - outputs[100][point])
    assert np.all(diff <= TOL), diff


@pytest.mark.parametrize("point", sorted(POINTS))
def test_error_shrinks_with_refinement(outputs, point):
    # distance to the finest grid (n_d = 200) falls from the production grid (n_d = 50) on,
    # and even n_d = 25 is within half the tolerance of it (theta scheme, module docstring)
    ref = outputs[200][point]
    err = np.stack([np.abs(outputs[n][point] - ref) for n in (25, 50, 100)])
    big = err[1] > 10 * np.array([1e-6, 1e-6, 1e-8])  # skip channels at round-off
    assert np.any(big)
    assert np.all(err[2, big] < err[1, big])
    assert np.all(err[0] <= 0.5 * TOL), err


def test_n_d_25_50_100_agree_within_the_readme_claim(outputs):
    worst = np.zeros(3)
    for point in POINTS:
        ys = np.stack([outputs[n][point] for n in (25, 50, 100)])
        worst = np.maximum(worst, ys.max(axis=0) - ys.min(axis=0))
    assert np.all(worst <= CLAIM), worst
