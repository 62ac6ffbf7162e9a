"""The polish after the study (``softsensor/calibration/refine.py``): it lowers eq. 4 within
the bounds, in a bounded number of model runs; the alternatives' polish updates its
Jacobian instead of differencing it again."""

from __future__ import annotations

import numpy as np

from softsensor.calibration.chunked_run import evaluate_parameters
from softsensor.calibration.objective import irls_scale
from softsensor.calibration.refine import BroydenResiduals, refine


def test_polish_lowers_the_cost_within_bounds(model, segment, config, eq4):
    start = np.array([0.3, 0.5, 3.0, 1.0, 4.0, 1e-5, 30.0])
    bounds = config.bounds()
    bounds[4, 1] = 4.5  # a tight upper bound on mult_p: the polish must respect it
    r = refine(model, [segment], start, bounds, eq4)
    assert r.improved and r.evaluation.fit.cost < 0.6 * r.start.fit.cost
    assert np.all(r.theta >= bounds[:, 0]) and np.all(r.theta <= bounds[:, 1])
    assert r.simulations <= 100  # two passes of at most 6 evaluations of 1 + 7 members


def test_broyden_carries_the_jacobian_without_differencing_again(model, segment, config, eq4):
    """The alternatives' polish (:class:`BroydenResiduals`): after the first differenced
    Jacobian, the one at the next point costs no simulation beyond the residuals there, maps
    the step onto the residuals' change (the secant condition) and differs from the first by
    a rank-one term."""
    z0 = np.log(config.parameter_vector())
    ev = evaluate_parameters(model, [segment], np.exp(z0), eq4)[0]
    prob = BroydenResiduals(model, [segment], eq4, irls_scale(ev, eq4), z0,
                            np.ones(z0.size, dtype=bool))
    e0 = prob.fun(z0).copy()
    J0 = prob.jac(z0)
    assert prob.simulations == 1 + z0.size  # the point and one member per parameter
    z1 = z0 + 0.05 * np.linspace(-1.0, 1.0, z0.size)
    e1 = prob.fun(z1)
    J1 = prob.jac(z1)
    assert prob.simulations == 2 + z0.size  # only the residuals at z1
    np.testing.assert_allclose(J1 @ (z1 - z0), e1 - e0, rtol=1e-9, atol=1e-9 * np.abs(e1).max())
    assert np.linalg.matrix_rank(J1 - J0, tol=1e-9 * np.abs(J0).max()) == 1
